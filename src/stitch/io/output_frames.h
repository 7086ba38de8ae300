#pragma once
// The frame and units each output is in, as its header states them (TUM "# frame:" lines, PLY
// "comment frame:" lines); docs/frames-and-units.md says the same at length.

namespace stitch::output_frames {

// A merged map (trajectory.tum, map.ply, colmap/): the frame of its largest submap.
inline constexpr const char* kLargestMap =
    "the largest merged map's: the camera of its largest submap's first keyframe (x right, y down, z along the "
    "optical axis), units of that camera's median scene depth when the submap began (monocular: not metres)";
// One map of trajectories/ in its own frame.
inline constexpr const char* kOwnMap =
    "this map's own: the camera of its largest submap's first keyframe (x right, y down, z along the optical axis), "
    "units of that camera's median scene depth when the submap began (monocular: not metres)";
// submaps.ply: every submap's points in that submap's own frame (they overlap).
inline constexpr const char* kEachSubmap =
    "each submap's own: the camera of its first keyframe (x right, y down, z along the optical axis), units of that "
    "camera's median scene depth when the submap began; submaps are not aligned with each other here";
// groundtruth.tum and rendered clips' truth.
inline constexpr const char* kGroundTruth = "the ground truth's, as the dataset states it (metres)";

}  // namespace stitch::output_frames
