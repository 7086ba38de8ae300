#pragma once
// When a tracked frame becomes a keyframe (ORB-SLAM2's decision): when it tracks fewer than
// options.keyframe_ratio of the points its reference keyframe holds (points seen by at least 3
// keyframes, 2 while the map has two), but more than 15, and the mapper has taken every
// keyframe sent so far (or is not connected).

#include "stitch/map/map.h"
#include "stitch/tracking/tracking_options.h"

namespace stitch {

struct KeyframeDecisionInput {
  int tracked_points = 0;     // the frame's points, after the local map
  int reference_points = 0;   // ReferencePoints() of its reference keyframe
  bool has_reference = true;  // false: the reference keyframe is gone (culled): always a keyframe
  int frames_since_keyframe = 0;
  bool mapper_ready = true;  // the mapper has caught up (or is not connected)
};

// Points of `reference` (in `map`) observed often enough to count for the decision.
int ReferencePoints(const Map& map, const Keyframe& reference);

// `fps`: the source's frame rate (the gap since the last keyframe is measured against one
// second of frames when options.max_keyframe_gap is 0).
bool NeedKeyframe(const KeyframeDecisionInput& input, const TrackingOptions& options, double fps);

}  // namespace stitch
