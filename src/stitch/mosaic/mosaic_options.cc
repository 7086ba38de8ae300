#include "stitch/mosaic/mosaic_options.h"

#include <cmath>

namespace stitch {

bool MosaicOptions::Check(std::string* why) const {
  const auto fail = [&](const char* text) { return *why = text, false; };
  if (!(gsd_m >= 0) || !std::isfinite(gsd_m)) return fail("gsd_m must be 0 (the images' own) or positive");
  if (tile_px < 16 || tile_px > 4096) return fail("tile_px must be in [16, 4096]");
  if (!(surface_cell_gsd >= 1) || !std::isfinite(surface_cell_gsd)) return fail("surface_cell_gsd must be at least 1");
  if (surface_min_points < 1) return fail("surface_min_points must be at least 1");
  if (!(max_off_nadir_deg > 0 && max_off_nadir_deg < 89)) return fail("max_off_nadir_deg must be in (0, 89)");
  if (image_border_px < 0 || image_border_px > 1000) return fail("image_border_px must be in [0, 1000]");
  if (max_pixels < 1) return fail("max_pixels must be positive");
  if (!(interval_s >= 0.05 && interval_s <= 3600)) return fail("interval_s must be in [0.05, 3600]");
  if (!(live_max_relief >= 0) || !std::isfinite(live_max_relief)) return fail("live_max_relief must be 0 or positive");
  if (live_min_pictures < 1) return fail("live_min_pictures must be at least 1");
  if (!(live_max_cpu_ms_per_picture >= 0) || !std::isfinite(live_max_cpu_ms_per_picture)) {
    return fail("live_max_cpu_ms_per_picture must be 0 (no limit) or positive");
  }
  return true;
}

}  // namespace stitch
