#pragma once
// Settings of the local mapping algorithm (the `mapper.mapping:` section of a stitch config). A
// light header: the configuration includes it without the mapper's code.

#include <string>

#include "stitch/estimators/bundle_adjustment.h"

namespace stitch {

struct MappingOptions {
  int triangulation_neighbours = 20;  // covisible keyframes to triangulate with
  // Baseline / median depth to try a neighbour at all. Each point must still show 1.1 degrees of
  // parallax, so a shorter baseline adds only near points that do; it moves only a handheld
  // camera that mostly rotates (TUM fr1/rpy), not the synthetic flights (docs/benchmarks.md).
  double min_baseline_ratio = 0.005;
  int fuse_neighbours = 20;             // first-order neighbours searched for duplicates
  double point_min_found_ratio = 0.25;  // recent points found in fewer of the frames predicting them are culled
  int point_min_observations = 2;       // recent points with this few observations after 2 keyframes are culled
  double keyframe_redundancy = 0.9;     // keyframes whose points are this much seen by 3 others are culled
  bool cull_keyframes = true;
  // Culled keyframes (and the frames tracked against them) are placed at the end by the points
  // they observed, refined since, rather than only through their parent at the relative pose
  // they had when culled.
  bool repose_culled_keyframes = true;
  BundleAdjustmentOptions local_bundle_adjustment;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("triangulation_neighbours", triangulation_neighbours, "covisible keyframes to triangulate new points with");
    v("min_baseline_ratio", min_baseline_ratio,
      "baseline / median depth below which a neighbour is not used (each point still needs 1.1 degrees "
      "of parallax)");
    v("fuse_neighbours", fuse_neighbours, "neighbour keyframes searched for duplicate points");
    v("point_min_found_ratio", point_min_found_ratio,
      "new points found in fewer of the keyframes predicting them are culled");
    v("point_min_observations", point_min_observations,
      "new points observed this few times after two keyframes are culled");
    v("keyframe_redundancy", keyframe_redundancy,
      "keyframes whose points this fraction is seen by 3 others are culled");
    v("cull_keyframes", cull_keyframes, "remove redundant keyframes");
    v("repose_culled_keyframes", repose_culled_keyframes,
      "pose culled keyframes (and the frames tracked against them) against the refined points they observed when "
      "written out or let go (else through their parent, at the relative pose they had when culled)");
    v("local_bundle_adjustment", local_bundle_adjustment, "local bundle adjustment");
  }
  bool Check(std::string* why) const;
};

}  // namespace stitch
