#pragma once
// Every tracked frame in its merged map: the pose the tracker reported (in its submap, and
// relative to the keyframe it was tracked against) re-composed with the newest pose of that
// keyframe, moved by its submap's placement and by the pose graph's correction of the nearest
// keyframe. `stitch run` applies it to frames.tsv at the end of a run; the merger applies it to the
// aircraft's pose stream (<agent>/POSE) during the flight, so the ground writes trajectory.tum.

#include <cstdint>
#include <map>
#include <vector>

#include "stitch/geometry/rigid3.h"
#include "stitch/records/pose_record.h"

namespace stitch {

// A frame as the tracker reported it.
struct TrackedFramePose {
  int frame_index = -1;
  int64_t t_ns = 0;
  int64_t submap_id = -1;
  bool is_keyframe = false;
  Rigid3d world_from_cam;           // in the submap's frame, as tracked
  int64_t reference_keyframe = -1;  // the keyframe it was tracked against (-1: none)
  Rigid3d cam_from_reference;       // relative to that keyframe
};

// A keyframe's newest pose in its submap (the mapper's, or the ground's copy of it).
struct KeyframeInSubmap {
  Rigid3d cam_from_world;
  int frame_index = -1;
};

// Where a submap sits: its merged map (component) and its frame in that map's.
struct SubmapInMap {
  int component = -1;
  Sim3d world_from_submap;
};

// Each frame in the order given: in its merged map where `placement` knows its submap (component
// and pose in that map's frame), else in its submap's own frame with component -1.
// `refined_world_from_cam`: keyframes the pose graph and bundle adjustment moved, in their merged
// map's frame; each frame follows the correction of its submap's keyframe nearest in frame number.
std::vector<PoseRecord> PlaceTrackedFrames(const std::vector<TrackedFramePose>& frames,
                                           const std::map<int64_t, KeyframeInSubmap>& keyframes,
                                           const std::map<int64_t, SubmapInMap>& placement,
                                           const std::map<int64_t, Sim3d>& refined_world_from_cam);

}  // namespace stitch
