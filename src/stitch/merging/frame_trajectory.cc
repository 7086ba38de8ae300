#include "stitch/merging/frame_trajectory.h"

#include <iterator>

#include "stitch/util/ids.h"

namespace stitch {

std::vector<PoseRecord> PlaceTrackedFrames(const std::vector<TrackedFramePose>& frames,
                                           const std::map<int64_t, KeyframeInSubmap>& keyframes,
                                           const std::map<int64_t, SubmapInMap>& placement,
                                           const std::map<int64_t, Sim3d>& refined_world_from_cam) {
  // The pose graph's correction of each refined keyframe (refined against placed), by submap and
  // frame, so frames tracked against keyframes the mapper culled move with their neighbours.
  std::map<int64_t, std::map<int, Sim3d>> corrections;
  for (const auto& [id, refined] : refined_world_from_cam) {
    const auto in_submap = keyframes.find(id);
    const auto placed = placement.find(SubmapOf(KeyframeId(id)).value);
    if (in_submap == keyframes.end() || placed == placement.end()) continue;
    const Rigid3d submap_from_cam = in_submap->second.cam_from_world.Inverse();
    const Sim3d placed_pose =
        placed->second.world_from_submap * Sim3d(1.0, submap_from_cam.rotation, submap_from_cam.translation);
    corrections[placed->first][in_submap->second.frame_index] = refined * placed_pose.Inverse();
  }
  std::vector<PoseRecord> poses;
  poses.reserve(frames.size());
  for (const TrackedFramePose& f : frames) {
    PoseRecord p;
    p.frame_index = f.frame_index;
    p.t_ns = f.t_ns;
    p.submap_id = f.submap_id;
    p.is_keyframe = f.is_keyframe;
    p.world_from_cam = f.world_from_cam;
    const auto reference = keyframes.find(f.reference_keyframe);
    if (f.reference_keyframe >= 0 && reference != keyframes.end()) {
      p.world_from_cam = (f.cam_from_reference * reference->second.cam_from_world).Inverse();
    }
    const auto placed = placement.find(f.submap_id);
    if (placed == placement.end()) {
      poses.push_back(p);
      continue;
    }
    p.component = placed->second.component;
    Sim3d world_from_cam =
        placed->second.world_from_submap * Sim3d(1.0, p.world_from_cam.rotation, p.world_from_cam.translation);
    const auto submap_corrections = corrections.find(f.submap_id);
    if (submap_corrections != corrections.end() && !submap_corrections->second.empty()) {
      const auto& by_frame = submap_corrections->second;
      auto next = by_frame.lower_bound(f.frame_index);
      if (next == by_frame.end() ||
          (next != by_frame.begin() && f.frame_index - std::prev(next)->first < next->first - f.frame_index)) {
        next = std::prev(next);
      }
      world_from_cam = next->second * world_from_cam;
    }
    p.world_from_cam = Rigid3d(world_from_cam.rotation, world_from_cam.translation);
    poses.push_back(p);
  }
  return poses;
}

}  // namespace stitch
