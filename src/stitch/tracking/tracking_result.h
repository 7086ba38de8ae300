#pragma once
// What the tracker says about each frame: its state, why, the pose, counts and timings.

#include <optional>
#include <string>

#include "stitch/geometry/rigid3.h"
#include "stitch/util/ids.h"

namespace stitch {

enum class TrackingState { kInitializing, kOk, kLost, kSkipped, kNotTracked };
enum class TrackingReason {
  kNone,
  kTooFewFeatures,
  kTooFewMatches,
  kInitFailed,
  kPoseDiverged,
  kUndecodableFrame,
  kDropped,
  kNoTracker,
  kMotionBlur,
  kNotRelocalized,
};

const char* TrackingStateName(TrackingState state);
const char* TrackingReasonName(TrackingReason reason);

// Where a frame's time went, milliseconds.
struct TrackTimings {
  double extraction = 0;      // ORB features and their undistortion
  double frame_to_frame = 0;  // motion model, homography or reference keyframe: matching and pose
  double local_map = 0;       // local map: selection, projection search, pose
  double keyframe = 0;        // keyframe decision and creation
  double total = 0;
};

struct TrackResult {
  TrackingState state = TrackingState::kNotTracked;
  TrackingReason reason = TrackingReason::kNone;
  std::string detail;
  SubmapId submap;
  std::optional<Rigid3d> cam_from_submap;
  KeyframeId reference_keyframe;  // for re-composing the pose with refined keyframes
  std::optional<Rigid3d> cam_from_reference;
  int num_features = 0;
  int num_tracked_points = 0;
  bool is_keyframe = false;
  bool relocalized = false;  // the pose comes from relocalization (in a kept or reopened submap)
  // How the frame was first placed: "motion model", "homography", "reference keyframe", ...
  const char* tracked_by = "";
  int submap_keyframes = 0;
  TrackTimings timings;
};

}  // namespace stitch
