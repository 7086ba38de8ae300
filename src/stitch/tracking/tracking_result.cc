#include "stitch/tracking/tracking_result.h"

namespace stitch {

const char* TrackingStateName(TrackingState state) {
  switch (state) {
    case TrackingState::kInitializing:
      return "INITIALIZING";
    case TrackingState::kOk:
      return "OK";
    case TrackingState::kLost:
      return "LOST";
    case TrackingState::kSkipped:
      return "SKIPPED";
    case TrackingState::kNotTracked:
      return "NOT_TRACKED";
  }
  return "?";
}

const char* TrackingReasonName(TrackingReason reason) {
  switch (reason) {
    case TrackingReason::kNone:
      return "none";
    case TrackingReason::kTooFewFeatures:
      return "too few features";
    case TrackingReason::kTooFewMatches:
      return "too few matches";
    case TrackingReason::kInitFailed:
      return "initialization failed";
    case TrackingReason::kPoseDiverged:
      return "pose optimization diverged";
    case TrackingReason::kUndecodableFrame:
      return "undecodable frame";
    case TrackingReason::kDropped:
      return "dropped";
    case TrackingReason::kNoTracker:
      return "no tracker";
    case TrackingReason::kMotionBlur:
      return "motion blur";
    case TrackingReason::kNotRelocalized:
      return "not relocalized";
  }
  return "?";
}

}  // namespace stitch
