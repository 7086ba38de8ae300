#include "services/tracker/frame_tracker.h"

namespace stitch {

const char* TrackingStateName(TrackingState state) {
  switch (state) {
    case TrackingState::kInitializing: return "INITIALIZING";
    case TrackingState::kOk: return "OK";
    case TrackingState::kLost: return "LOST";
    case TrackingState::kSkipped: return "SKIPPED";
    case TrackingState::kNotTracked: return "NOT_TRACKED";
  }
  return "?";
}

const char* TrackingReasonName(TrackingReason reason) {
  switch (reason) {
    case TrackingReason::kNone: return "none";
    case TrackingReason::kTooFewFeatures: return "too few features";
    case TrackingReason::kTooFewMatches: return "too few matches";
    case TrackingReason::kInitFailed: return "initialization failed";
    case TrackingReason::kPoseDiverged: return "pose optimization diverged";
    case TrackingReason::kUndecodableFrame: return "undecodable frame";
    case TrackingReason::kDropped: return "dropped";
    case TrackingReason::kNoTracker: return "no SLAM core yet";
  }
  return "?";
}

TrackResult FrameTracker::Track(const cv::Mat& /*image*/, int64_t /*t_ns*/, int /*frame_index*/) {
  TrackResult result;
  result.state = TrackingState::kNotTracked;
  result.reason = TrackingReason::kNoTracker;
  result.detail = "the monocular SLAM core is not built yet (issue #3)";
  return result;
}

}  // namespace stitch
