#pragma once
// One merged map as a single Map (DESIGN.md, step 4, after the pose graph): every keyframe of
// the merged submaps at its refined pose in the merged map's frame, their points carried with
// their reference keyframes, the same physical point seen from two submaps fused into one (first
// the verified matches of the connected frames, then by projection between the keyframes around
// each connection), and a global bundle adjustment over all of it. Fusing is what lets the
// adjustment re-triangulate the junction between two submaps from both sides, where the edge's
// Sim3 alone rests on a few dozen points.

#include <map>
#include <vector>

#include "services/merger/submap_graph.h"
#include "stitch/estimators/bundle_adjustment.h"
#include "stitch/map/map.h"
#include "stitch/map/submap_update.h"

namespace stitch {

struct MergedMapOptions {
  bool fuse_points = true;              // fuse duplicates across submaps
  int fuse_window = 10;                 // covisible keyframes taken around each connected keyframe
  double fuse_radius_px = 3.0;          // search radius (x level scale) when fusing by projection
  bool bundle_adjustment = true;        // global bundle adjustment after fusing
  int bundle_adjustment_iterations = 10;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("fuse_points", fuse_points, "fuse the same point seen from two merged submaps into one");
    v("fuse_window", fuse_window, "covisible keyframes around each connected keyframe searched for duplicates");
    v("fuse_radius_px", fuse_radius_px, "search radius in pixels (times the level's scale) when fusing by projection");
    v("bundle_adjustment", bundle_adjustment, "global bundle adjustment of each merged map after the pose graph");
    v("bundle_adjustment_iterations", bundle_adjustment_iterations, "iterations of each global bundle adjustment pass");
  }
  bool Check(std::string* why) const;
};

struct MergedMap {
  int component = -1;
  Map map;                                    // in the merged map's frame; ids as in the submaps
  std::map<KeyframeId, Sim3d> keyframe_poses; // world_from_cam, the scale being the keyframe's submap's
  int points_fused_by_connection = 0;         // verified matches of connected frames made one point
  int points_fused_by_projection = 0;
  BundleAdjustmentReport bundle_adjustment;

  explicit MergedMap(const ScalePyramid& pyramid) : map(SubmapId(), pyramid) {}
};

// Builds merged map `component`: `placement` and `keyframe_poses` as Merger::Solve gives them
// (keyframe_poses may be empty: then the tree's placement); `connections` the verified connected
// frames that agree with that placement.
MergedMap AssembleMergedMap(const std::map<SubmapId, SubmapReplica>& submaps,
                            const std::map<SubmapId, SubmapPlacement>& placement,
                            const std::map<KeyframeId, Sim3d>& keyframe_poses,
                            const std::vector<ConnectedFrame>& connections, int component, const ScalePyramid& pyramid,
                            const PinholeIntrinsics& intrinsics, const MergedMapOptions& options);

}  // namespace stitch
