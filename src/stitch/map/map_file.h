#pragma once
// A saved map (`.stitchmap`, docs/map-file.md): one map's keyframes (pose, features, descriptors,
// associations, camera) and points in one frame, as a flight's merged map left them, to be
// loaded by a later flight (`stitch run --map`) or another tool. Versioned and checksummed: a
// file that is damaged, cut short, of another version or not a map is refused with what is
// wrong; nothing read from one is trusted before it is checked (every count against the bytes
// left, every index in range, every number finite). Encoding is deterministic: a map read and
// written again is the same bytes.

#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "stitch/geometry/camera.h"
#include "stitch/map/map.h"

namespace stitch {

// The format's version this build writes and reads; a file of another version is refused
// (MapFileVersionError) rather than misread.
constexpr uint32_t kMapFileVersion = 1;

struct SavedMap {
  std::string description;                        // where it came from (free text, at most 64 kB)
  std::vector<Camera> cameras;                    // at least one
  Map map;                                        // keyframes numbered 0.. and points 0.. in one submap; no caches
  std::map<KeyframeId, int> camera_index;         // each keyframe's, into `cameras`
  std::map<KeyframeId, int64_t> source_keyframe;  // each keyframe's id in the flight it came from

  explicit SavedMap(Map m) : map(std::move(m)) {}
  const Camera& CameraOf(KeyframeId keyframe) const { return cameras.at(camera_index.at(keyframe)); }
};

// Builds a saved map from `map` (any keyframe and point ids, e.g. a merged map of several
// submaps): keyframes renumbered in id order, points in id order, each keyframe's camera from
// `camera_of(keyframe id)`; a keyframe it gives none for (its camera never arrived) is left out,
// and so are points no kept keyframe observes.
SavedMap MakeSavedMap(const Map& map, const std::function<const Camera*(KeyframeId)>& camera_of,
                      const std::string& description, SubmapId id);

// The file's bytes (header, then the checksummed payload).
std::string EncodeMapFile(const SavedMap& saved);
// Throws stitch::Error saying what is wrong; the map is given submap id `id`.
SavedMap DecodeMapFile(const std::string& bytes, SubmapId id);

// Writes atomically (a temporary file renamed over `path`). Throws stitch::Error.
void WriteMapFile(const std::string& path, const SavedMap& saved);
// Throws stitch::Error naming the file and what is wrong with it.
SavedMap ReadMapFile(const std::string& path, SubmapId id);

// What a file holds, from its header and payload, for `stitch map info`.
struct MapFileSummary {
  uint32_t version = 0;
  uint64_t bytes = 0;
  std::string checksum;  // the payload's BLAKE2b-256, hex
  std::string description;
  int cameras = 0, keyframes = 0, points = 0;
  int64_t observations = 0;
};
MapFileSummary SummarizeMapFile(const std::string& bytes, const SavedMap& saved);

}  // namespace stitch
