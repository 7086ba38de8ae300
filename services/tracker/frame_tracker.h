#pragma once
// The tracker's per-frame algorithm, free of LCM. It owns the current map's tracking state and
// is used from one thread.
//
// Status: the monocular SLAM core (ORB features, initialization, pose tracking, keyframes) is
// issue #3. Until it lands, Track() reports every frame as NOT_TRACKED with reason NO_TRACKER,
// and stitch run says so rather than inventing poses.

#include <cstdint>
#include <optional>
#include <string>

#include <opencv2/core.hpp>

#include "stitch/geometry/camera.h"
#include "stitch/geometry/rigid3.h"

namespace stitch {

enum class TrackingState { kInitializing, kOk, kLost, kSkipped, kNotTracked };
enum class TrackingReason { kNone, kTooFewFeatures, kTooFewMatches, kInitFailed, kPoseDiverged, kUndecodableFrame, kDropped, kNoTracker };

const char* TrackingStateName(TrackingState state);
const char* TrackingReasonName(TrackingReason reason);

struct TrackResult {
  TrackingState state = TrackingState::kNotTracked;
  TrackingReason reason = TrackingReason::kNoTracker;
  std::string detail;
  int64_t submap_id = -1;
  std::optional<Rigid3d> cam_from_submap;
  int num_features = 0;
  int num_tracked_points = 0;
  bool is_keyframe = false;
};

class FrameTracker {
 public:
  explicit FrameTracker(const Camera& camera) : camera_(camera) {}
  TrackResult Track(const cv::Mat& image, int64_t t_ns, int frame_index);
  const Camera& camera() const { return camera_; }

 private:
  Camera camera_;
};

}  // namespace stitch
