#include "stitch/mapping/mapping_options.h"

namespace stitch {

bool MappingOptions::Check(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (triangulation_neighbours < 1 || fuse_neighbours < 0)
    return fail("mapper.mapping: neighbour counts must be positive");
  if (!(min_baseline_ratio >= 0)) return fail("mapper.mapping.min_baseline_ratio must be >= 0");
  if (!(point_min_found_ratio >= 0 && point_min_found_ratio <= 1))
    return fail("mapper.mapping.point_min_found_ratio must be in [0, 1]");
  if (point_min_observations < 2) return fail("mapper.mapping.point_min_observations must be >= 2");
  if (!(keyframe_redundancy > 0 && keyframe_redundancy <= 1))
    return fail("mapper.mapping.keyframe_redundancy must be in (0, 1]");
  return local_bundle_adjustment.Check(why);
}

}  // namespace stitch
