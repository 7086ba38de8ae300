#include "stitch/tracking/tracking_options.h"

#include "stitch/util/error.h"

namespace stitch {

bool FeatureFlowOptions::Check(std::string* why) const {
  const auto fail = [why](const char* text) {
    if (why) *why = text;
    return false;
  };
  if (max_frames < 1 || max_frames > 30) return fail("tracker.tracking.flow.max_frames must be in [1, 30]");
  if (window_px < 5 || window_px > 61 || window_px % 2 == 0)
    return fail("tracker.tracking.flow.window_px must be odd and in [5, 61]");
  if (levels < 0 || levels > 6) return fail("tracker.tracking.flow.levels must be in [0, 6]");
  if (!(max_error > 0 && max_error <= 255)) return fail("tracker.tracking.flow.max_error must be in (0, 255]");
  if (!(max_turn_deg >= 0 && max_turn_deg <= 45)) return fail("tracker.tracking.flow.max_turn_deg must be in [0, 45]");
  if (!(max_scale_change >= 0 && max_scale_change < 1)) {
    return fail("tracker.tracking.flow.max_scale_change must be in [0, 1)");
  }
  if (!(keyframe_margin >= 0 && keyframe_margin <= 1))
    return fail("tracker.tracking.flow.keyframe_margin must be in [0, 1]");
  return true;
}

bool TrackingOptions::Check(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (!orb.Check(why) || !flow.Check(why) || !initialization.Check(why)) return false;
  if (init_min_features < 8 || init_min_matches < 8)
    return fail("tracker.tracking: init_min_features and init_min_matches must be >= 8");
  if (init_window_px < 5) return fail("tracker.tracking.init_window_px must be >= 5");
  if (min_inliers < 6 || min_inliers_after_failure < min_inliers) {
    return fail("tracker.tracking: need 6 <= min_inliers <= min_inliers_after_failure");
  }
  if (lost_after_frames < 1) return fail("tracker.tracking.lost_after_frames must be >= 1");
  if (!(keyframe_ratio > 0 && keyframe_ratio < 1)) return fail("tracker.tracking.keyframe_ratio must be in (0, 1)");
  if (!(keyframe_ratio_along_axis >= keyframe_ratio && keyframe_ratio_along_axis < 1)) {
    return fail("tracker.tracking.keyframe_ratio_along_axis must be in [keyframe_ratio, 1)");
  }
  if (!(keyframe_along_axis_max_angle_deg >= 0 && keyframe_along_axis_max_angle_deg <= 90)) {
    return fail("tracker.tracking.keyframe_along_axis_max_angle_deg must be in [0, 90]");
  }
  if (!(keyframe_min_parallax_deg >= 0 && keyframe_min_parallax_deg <= 90)) {
    return fail("tracker.tracking.keyframe_min_parallax_deg must be in [0, 90]");
  }
  if (keyframes_in_flight < 1 || keyframes_in_flight > 8) {
    return fail("tracker.tracking.keyframes_in_flight must be in [1, 8]");
  }
  if (!(keyframe_ratio_without_parallax > 0 && keyframe_ratio_without_parallax <= keyframe_ratio)) {
    return fail("tracker.tracking.keyframe_ratio_without_parallax must be in (0, keyframe_ratio]");
  }
  if (!(keyframe_gap_without_parallax_s >= 0 && keyframe_gap_without_parallax_s <= 60)) {
    return fail("tracker.tracking.keyframe_gap_without_parallax_s must be in [0, 60]");
  }
  if (!(keyframe_min_coverage >= 0 && keyframe_min_coverage <= 1)) {
    return fail("tracker.tracking.keyframe_min_coverage must be in [0, 1]");
  }
  if (max_keyframe_gap < 0) return fail("tracker.tracking.max_keyframe_gap must be >= 0");
  if (!(min_relative_sharpness >= 0 && min_relative_sharpness < 1))
    return fail("tracker.tracking.min_relative_sharpness must be in [0, 1)");
  if (!(rolling_shutter_line_us == -1 || (rolling_shutter_line_us >= 0 && rolling_shutter_line_us <= 1000)))
    return fail("tracker.tracking.rolling_shutter_line_us must be -1 (the source's) or in [0, 1000]");
  if (!(resume_max_parallax_deg >= 0 && resume_max_parallax_deg <= 90)) {
    return fail("tracker.tracking.resume_max_parallax_deg must be in [0, 90]");
  }
  if (!(keyframe_coverage_min_parallax_deg >= 0 && keyframe_coverage_min_parallax_deg <= 90)) {
    return fail("tracker.tracking.keyframe_coverage_min_parallax_deg must be in [0, 90]");
  }
  if (relocalize_closed_after_frames < 0) return fail("tracker.tracking.relocalize_closed_after_frames must be >= 0");
  if (return_to_closed_frames < 0) return fail("tracker.tracking.return_to_closed_frames must be >= 0");
  if (submap_max_keyframes != 0 && submap_max_keyframes < 10) {
    return fail("tracker.tracking.submap_max_keyframes must be 0 (no cap) or at least 10");
  }
  if (handover_keyframes < 2 || (submap_max_keyframes > 0 && handover_keyframes >= submap_max_keyframes / 2)) {
    return fail("tracker.tracking.handover_keyframes must be at least 2 and below half of submap_max_keyframes");
  }
  if (closed_keyframes_held < 0) return fail("tracker.tracking.closed_keyframes_held must be >= 0");
  if (return_to_closed_every < 1) return fail("tracker.tracking.return_to_closed_every must be >= 1");
  if (retrack_missed_frames < 0 || retrack_missed_frames > 300)
    return fail("tracker.tracking.retrack_missed_frames must be in [0, 300]");
  if (relocalization_candidates < 1) return fail("tracker.tracking.relocalization_candidates must be >= 1");
  if (relocalization_min_inliers < min_inliers)
    return fail("tracker.tracking.relocalization_min_inliers must be >= min_inliers");
  if (reference_matching != "bow" && reference_matching != "lsh" && reference_matching != "brute_force") {
    return fail("tracker.tracking.reference_matching must be bow, lsh or brute_force");
  }
  if (!(homography_threshold_px > 0 && homography_threshold_px <= 100))
    return fail("tracker.tracking.homography_threshold_px must be in (0, 100]");
  if (!(homography_search_px > 0 && homography_search_px <= 200))
    return fail("tracker.tracking.homography_search_px must be in (0, 200]");
  if (homography_roi_per_cell < 0 || homography_roi_per_cell > 1000)
    return fail("tracker.tracking.homography_roi_per_cell must be in [0, 1000]");
  if (saved_map_follow_frames < 0) return fail("tracker.tracking.saved_map_follow_frames must be >= 0");
  if (localize_only && prior_map.empty())
    return fail("tracker.tracking.localize_only needs a prior_map (stitch run --map)");
  if (agent_number < 0 || agent_number >= kSavedMapAgent) {
    return fail("tracker.tracking.agent_number must be in [0, 32766] (32767 names saved maps)");
  }
  if (first_submap_number < 1 || first_submap_number > 65535)
    return fail("tracker.tracking.first_submap_number must be in [1, 65535]");
  return true;
}

LossPolicy ParseLossPolicy(const std::string& name) {
  if (name == "submap") return LossPolicy::kNewSubmap;
  if (name == "relocalize") return LossPolicy::kRelocalize;
  throw Error("the loss policy must be submap or relocalize, not '" + name + "'");
}

}  // namespace stitch
