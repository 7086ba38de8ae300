#pragma once
// poses.tsv: every posed frame's final pose, with its submap and merged map. Written by `stitch
// run` / `stitch eval` (run_outputs), read by the evaluation of a finished run folder.

#include <cstdint>
#include <string>
#include <vector>

#include "stitch/geometry/rigid3.h"

namespace stitch {

// One frame's final pose: where the run placed it, in which submap and merged map.
struct PoseRecord {
  int frame_index = -1;
  int64_t t_ns = 0;
  int64_t submap_id = -1;
  int component = -1;  // merged map; equal values share one frame
  bool is_keyframe = false;
  Rigid3d world_from_cam;  // in the component's frame (its scale is arbitrary)
};

// poses.tsv: "frame_index t_ns submap_id component keyframe tx ty tz qx qy qz qw". Both throw
// stitch::Error naming the file (and line).
std::vector<PoseRecord> ReadPoseRecords(const std::string& path);
void WritePoseRecords(const std::string& path, const std::vector<PoseRecord>& poses);

// The maps of a run's poses, named as its outputs name them: a merged map of several submaps
// "map-K" (K = 0 the largest, then by frames), a submap on its own "submap-A-N"; the largest
// map first, then by frames.
struct RunMap {
  int component = -1;
  std::string name;
  int frames = 0;
  std::vector<int64_t> submaps;  // ascending
  bool largest = false;

  std::string SubmapNames() const;  // "0:1,0:2"
};
std::vector<RunMap> MapsOfRun(const std::vector<PoseRecord>& poses, int largest_component);

}  // namespace stitch
