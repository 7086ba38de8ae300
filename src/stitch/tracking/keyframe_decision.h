#pragma once
// When a tracked frame becomes a keyframe (ORB-SLAM2's decision, plus parallax): when it tracks
// fewer than options.keyframe_ratio of the points its reference keyframe holds (points seen by
// at least 3 keyframes, 2 while the map has two), but more than 15, and the mapper has taken
// every keyframe sent so far (or is not connected). A frame whose median parallax with the
// reference is under options.keyframe_min_parallax_deg (a camera that mostly rotates: a keyframe
// there adds little triangulation, only cost) becomes one only once
// options.keyframe_gap_without_parallax_s of the sequence has passed since the last keyframe, or
// at once when it tracks fewer than options.keyframe_ratio_without_parallax of the points (much
// new ground in view). A frame with that parallax moving along its viewing direction (a forward
// camera) becomes one below options.keyframe_ratio_along_axis instead of keyframe_ratio.

#include "stitch/map/map.h"
#include "stitch/tracking/tracking_options.h"

namespace stitch {

struct KeyframeDecisionInput {
  int tracked_points = 0;     // the frame's points, after the local map
  int reference_points = 0;   // ReferencePoints() of its reference keyframe
  bool has_reference = true;  // false: the reference keyframe is gone (culled): always a keyframe
  int frames_since_keyframe = 0;
  bool mapper_ready = true;  // the mapper has caught up (or is not connected)
  // Median angle at the frame's tracked points between the rays from the reference keyframe's
  // centre and the frame's (MedianParallaxDeg); negative: not measured.
  double parallax_deg = -1;
  // Angle between the frame's optical axis and its displacement since the reference keyframe
  // (either way along it), degrees (MotionAxisAngleDeg); negative: not measured or no motion.
  double motion_axis_angle_deg = -1;
  // Share of the image's feature-holding cells in which the frame tracks a map point
  // (TrackedCoverage); negative: not measured.
  double tracked_coverage = -1;
};

// Points of `reference` (in `map`) observed often enough to count for the decision.
int ReferencePoints(const Map& map, const Keyframe& reference);

// Median over the frame's tracked points (posed frame, points in `map`) of the angle between the
// rays from `reference`'s centre and the frame's centre: what the camera's motion since the
// reference adds to triangulation (0 for a pure rotation). -1 when no point is tracked.
double MedianParallaxDeg(const Map& map, const Keyframe& reference, const Frame& frame);

// The angle, degrees, between `frame`'s optical axis and the line from `reference`'s centre to the
// frame's (0: moving straight ahead or back; 90: sideways, as a downward camera flying level). -1
// when the frame is not posed or has not moved.
double MotionAxisAngleDeg(const Keyframe& reference, const Frame& frame);

// The tracked share of the reference's points under which NeedKeyframe may make this input a
// keyframe: options.keyframe_ratio, or keyframe_ratio_along_axis (at least keyframe_ratio) when
// the camera moves along its viewing direction (motion_axis_angle_deg within keyframe_along_axis_max_angle_deg);
// the latter needs keyframe_min_parallax_deg of parallax, so a rotating camera keeps the former.
double KeyframeRatio(const KeyframeDecisionInput& input, const TrackingOptions& options);

// Of the cells of an 8x6 grid over the image that hold at least 3 of the frame's features, the
// share in which at least one feature is a tracked map point: how much of what the camera sees the
// map already covers (1: all of it; low: the camera looks at ground the map does not hold yet).
double TrackedCoverage(const Frame& frame, int width, int height);

// `fps`: the source's frame rate (the gap since the last keyframe is measured against one
// second of frames when options.max_keyframe_gap is 0).
bool NeedKeyframe(const KeyframeDecisionInput& input, const TrackingOptions& options, double fps);

}  // namespace stitch
