#pragma once
// One merged map as a single Map (docs/method.md, step 4, after the pose graph): every keyframe of
// the merged submaps at its refined pose in the merged map's frame, their points carried with
// their reference keyframes, the same physical point seen from two submaps fused into one (first
// the verified matches of the connected frames, then by projection between the keyframes around
// each connection), and a global bundle adjustment over all of it. Fusing is what lets the
// adjustment re-triangulate the junction between two submaps from both sides, where the edge's
// Sim3 alone rests on a few dozen points.

#include <map>
#include <string>
#include <utility>
#include <vector>

#include "stitch/estimators/bundle_adjustment.h"
#include "stitch/map/map.h"
#include "stitch/map/submap_update.h"
#include "stitch/merging/gnss_junctions.h"
#include "stitch/merging/merger_options.h"
#include "stitch/merging/submap_graph.h"

namespace stitch {

// The observations that join two submaps of a merged map: of a point from one submap, made by a
// keyframe of the other (fusing makes them). `joined`: made by fusing; `kept`: those within the
// adjustment's outlier bound (chi-square 5.991) after the bundle adjustments, which drop an
// observation its point and keyframe cannot agree on. A placement the points around the
// junction confirm keeps nearly all (docs/merger.md, "Checked after placement").
struct Junction {
  int joined = 0;
  int kept = 0;
};

struct MergedMap {
  int component = -1;
  Map map;                                     // in the merged map's frame; ids as in the submaps
  std::map<KeyframeId, Sim3d> keyframe_poses;  // world_from_cam, the scale being the keyframe's submap's
  int points_fused_by_connection = 0;          // verified matches of connected frames made one point
  int points_fused_by_projection = 0;
  BundleAdjustmentReport bundle_adjustment;
  std::map<std::pair<SubmapId, SubmapId>, Junction> junctions;  // by the pair's ids, smaller first

  explicit MergedMap(const ScalePyramid& pyramid) : map(SubmapId(), pyramid) {}
};

// The aircraft's fixes where they put a merged map on Earth (Merger::Graph::on_earth): in its
// bundle adjustment each fix holds the antenna where it says, at the fix's time between two of its
// submap's keyframes (georeference: the antenna's offset, the time offset, the largest gap between
// the keyframes, the outlier bound).
struct FixesOnEarth {
  Sim3d enu_from_world;                // the merged map's frame into the fixes' ENU frame
  const SubmapFixes* fixes = nullptr;  // each submap's, in that frame
  const GeoReferenceOptions* georeference = nullptr;
};
// The priors `on_earth` makes on `map`'s keyframes (their submap's fixes, by their ids).
PositionPriors PriorsFromFixes(const Map& map, const FixesOnEarth& on_earth);

// Builds merged map `component`: `placement` and `keyframe_poses` as Merger::Solve gives them
// (keyframe_poses may be empty: then the tree's placement); `connections` the verified connected
// frames that agree with that placement; `on_earth` (may be null) its fixes, as priors in the
// adjustment where options.gnss_in_adjustment.
MergedMap AssembleMergedMap(const std::map<SubmapId, SubmapReplica>& submaps,
                            const std::map<SubmapId, SubmapPlacement>& placement,
                            const std::map<KeyframeId, Sim3d>& keyframe_poses,
                            const std::vector<ConnectedFrame>& connections, int component, const ScalePyramid& pyramid,
                            const PinholeIntrinsics& intrinsics, const MergedMapOptions& options,
                            const FixesOnEarth* on_earth = nullptr);

// The check after placement: the edges of `tree` inside `merged` (assembled with fused points)
// whose junction does not confirm them: fewer than `min_junction_observations` joining
// observations (fusing found too few points of either submap in the other where the merge put
// them), or less than `min_junction_kept` of them kept by the adjustment; each with why. Their
// merges are to be rolled back. Edges of `tree` in other merged maps are not judged (their
// junctions were not made).
struct DoubtedEdge {
  SubmapEdge edge;
  std::string reason;
};
std::vector<DoubtedEdge> CheckJunctions(const MergedMap& merged, const std::vector<SubmapEdge>& tree,
                                        const AcceptanceOptions& options);

}  // namespace stitch
