#include "stitch/merging/merger_options.h"

#include <cmath>

namespace stitch {

bool ConnectionWeights::Check(std::string* why) const {
  if (!(std::isfinite(frames) && std::isfinite(points) && std::isfinite(angle)) || frames < 0 || points < 0 ||
      angle < 0) {
    if (why) *why = "merger.connection_weights must be finite and >= 0";
    return false;
  }
  return true;
}

bool MergedMapOptions::Check(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (fuse_window < 0) return fail("merger.merged_map.fuse_window must be >= 0");
  if (!(fuse_radius_px > 0)) return fail("merger.merged_map.fuse_radius_px must be > 0");
  if (bundle_adjustment_iterations < 1) return fail("merger.merged_map.bundle_adjustment_iterations must be >= 1");
  if (bundle_adjustment_max_free_keyframes < 0) {
    return fail("merger.merged_map.bundle_adjustment_max_free_keyframes must be >= 0 (0: all)");
  }
  return true;
}

bool AcceptanceOptions::Check(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (!(min_line_ratio >= 0 && min_line_ratio < 1)) return fail("merger.acceptance.min_line_ratio must be in [0, 1)");
  if (!(min_bearing_spread >= 0 && min_bearing_spread < 1)) {
    return fail("merger.acceptance.min_bearing_spread must be in [0, 1) radians");
  }
  if (min_connected_frames < 1) return fail("merger.acceptance.min_connected_frames must be >= 1");
  if (!(min_agreement >= 0 && min_agreement <= 1)) return fail("merger.acceptance.min_agreement must be in [0, 1]");
  if (!(min_junction_kept >= 0 && min_junction_kept <= 1)) {
    return fail("merger.acceptance.min_junction_kept must be in [0, 1]");
  }
  if (min_junction_observations < 0) return fail("merger.acceptance.min_junction_observations must be >= 0");
  if (!(max_missing_keyframes >= 0 && max_missing_keyframes <= 1)) {
    return fail("merger.acceptance.max_missing_keyframes must be in [0, 1]");
  }
  return true;
}

bool MergerOptions::Check(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (!(min_connection_strength >= 0)) return fail("merger.min_connection_strength must be >= 0");
  if (max_candidates < 1) return fail("merger.max_candidates must be >= 1");
  if (candidate_window < 0 || candidate_window > 50) return fail("merger.candidate_window must be in [0, 50]");
  if (relocalization_min_inliers != 0 && relocalization_min_inliers < 12) {
    return fail("merger.relocalization_min_inliers must be 0 (off) or at least 12");
  }
  if (min_matches < 3 || sim3_min_inliers < 3)
    return fail("merger.min_matches and merger.sim3_min_inliers must be >= 3");
  if (!(match_ratio > 0 && match_ratio <= 1)) return fail("merger.match_ratio must be in (0, 1]");
  if (loop_min_separation < 1) return fail("merger.loop_min_separation must be >= 1");
  if (!(resend_interval_s > 0)) return fail("merger.resend_interval_s must be > 0");
  if (!(live_outputs_interval_s >= 0 && live_outputs_interval_s <= 3600))
    return fail("merger.live_outputs_interval_s must be within [0, 3600]");
  if (map_cloud_points < 0 || map_cloud_points > 5'000'000)
    return fail("merger.map_cloud_points must be within [0, 5000000]");
  std::string georeference_why;
  if (!georeference.Check(&georeference_why)) return fail("merger.georeference." + georeference_why);
  std::string mosaic_why;
  if (!mosaic.Check(&mosaic_why)) return fail("merger.mosaic." + mosaic_why);
  return connection_weights.Check(why) && merged_map.Check(why) && acceptance.Check(why) && map_export.Check(why);
}

}  // namespace stitch
