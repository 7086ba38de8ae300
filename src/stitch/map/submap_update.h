#pragma once
// What the merger learns of a submap (mapper -> merger, docs/messages.md): after each keyframe,
// that keyframe in full plus the changes around it; when the submap closes, its final state in
// full. A receiver rebuilds the submap by applying the updates to its own Map
// (ApplySubmapUpdate). Applying an update twice, or its parts in any order, leaves the same map.

#include <optional>
#include <vector>

#include "stitch/geometry/camera.h"
#include "stitch/map/local_map_update.h"
#include "stitch/map/map.h"

namespace stitch {

struct SubmapUpdate {
  SubmapId submap;
  int revision = 0;
  bool closed = false;                  // tracking left the submap: this is its final state
  bool full_state = false;              // `changes` covers every keyframe and point of the submap
  std::optional<Camera> camera;         // of the keyframes' images (comes with every keyframe)
  std::vector<Keyframe> new_keyframes;  // features, descriptors, pose, associations (no caches)
  LocalMapUpdate changes;               // poses, associations, points, removals
  std::vector<KeyframeId> manifest;     // every keyframe the submap holds now (may be empty in a part)
};

// The keyframe just mapped, in full, with the window's `changes` (as sent to the tracker).
SubmapUpdate MakeKeyframeSubmapUpdate(const Map& map, KeyframeId keyframe, const Camera& camera,
                                      const LocalMapUpdate& changes);
// The whole submap's poses, associations and points (no keyframe features: they were sent
// with their keyframes), plus the removals journaled since the last update.
SubmapUpdate MakeFullSubmapUpdate(Map* map, int revision, bool closed);

// Part of a submap again, for a receiver that lost it: those of `keyframes` the map holds, in full
// with the points they observe, and with `full_state` every pose, association and point (closed
// as `closed` says). A closed submap's keyframes without its state go alone, without their points
// or a manifest (the final state has them): send those as revision 0, older than any state.
SubmapUpdate MakeResendSubmapUpdate(Map* map, const Camera& camera, const std::vector<KeyframeId>& keyframes,
                                    bool full_state, bool closed, int revision);
// The submap's manifest alone (a few bytes per keyframe), sorted: lets a receiver that lost the
// newest keyframe's update notice it while no new keyframe comes. Empty for a map without keyframes.
SubmapUpdate MakeManifestSubmapUpdate(const Map& map, const Camera& camera, int revision);

// A receiver's copy of a submap (the merger's store holds one per submap).
struct SubmapReplica {
  SubmapReplica(SubmapId id, ScalePyramid pyramid) : map(id, std::move(pyramid)) {}

  Map map;
  std::optional<Camera> camera;
  bool closed = false;
  int newest_revision = -1;      // newest revision applied
  int manifest_revision = -1;    // revision of the manifest the keyframes follow
  int full_state_revision = -1;  // revision of the newest full state applied
  std::vector<KeyframeId> manifest;
};

// Applies an update to the receiver's copy: removals, points, new keyframes it does not have,
// associations and poses; keyframes a newer manifest does not list are removed. Changes older
// than a full state already applied are ignored (they arrived late), except keyframes the
// manifest still lacks. Returns the manifest's keyframes the copy lacks (lost on the way).
std::vector<KeyframeId> ApplySubmapUpdate(const SubmapUpdate& update, SubmapReplica* replica);

// Splits an update into parts of about `max_bytes` each when encoded: the first carries the
// removals, poses and manifest; then points, keyframes (never split, one per part when large)
// and associations.
std::vector<SubmapUpdate> SplitSubmapUpdate(const SubmapUpdate& update, size_t max_bytes);

// Encoded size of a keyframe in a message, bytes (docs/messages.md).
size_t KeyframeMessageBytes(const Keyframe& keyframe);

}  // namespace stitch
