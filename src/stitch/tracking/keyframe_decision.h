#pragma once
// When a tracked frame becomes a keyframe (ORB-SLAM2's decision, plus parallax): when it tracks
// fewer than options.keyframe_ratio of the points its reference keyframe holds (points seen by
// at least 3 keyframes, 2 while the map has two), but more than 15, and the mapper has taken
// every keyframe sent so far (or is not connected). A frame whose median parallax with the
// reference is under options.keyframe_min_parallax_deg (a camera that mostly rotates: a keyframe
// there adds little triangulation, only cost) becomes one only once
// options.keyframe_gap_without_parallax_s of the sequence has passed since the last keyframe, or
// at once when it tracks fewer than options.keyframe_ratio_without_parallax of the points (much
// new ground in view).

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

// Of the cells of an 8x6 grid over the image that hold at least 3 of the frame's features, the
// share in which at least one feature is a tracked map point: how much of what the camera sees the
// map already covers (1: all of it; low: the camera looks at ground the map does not hold yet).
double TrackedCoverage(const Frame& frame, int width, int height);

// `fps`: the source's frame rate (the gap since the last keyframe is measured against one
// second of frames when options.max_keyframe_gap is 0).
bool NeedKeyframe(const KeyframeDecisionInput& input, const TrackingOptions& options, double fps);

}  // namespace stitch
