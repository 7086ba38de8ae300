#pragma once
// The mapper's point-making stages, ORB-SLAM2's local mapping steps 3 and 4: new points
// triangulated between a new keyframe and its covisible keyframes, and duplicates fused with
// the neighbourhood. Plain functions over one map; the caller owns the map.

#include <vector>

#include "stitch/map/map.h"
#include "stitch/map/view_geometry.h"

namespace stitch {

// Unmatched features of `keyframe` and each of its `neighbours` best covisible keyframes (with a
// baseline of at least `min_baseline_ratio` of the neighbour's median depth) matched under the
// epipolar constraint, triangulated, and kept when in front of both cameras, within 5.991
// sigma^2 of both features, at a parallax above 1.1 degrees (cosine < 0.9998) and at distances
// that agree with the pyramid levels seen at. Returns the new points' ids, in creation order.
std::vector<MapPointId> TriangulateNewPoints(Map* map, KeyframeId keyframe, const ViewGeometry& geometry,
                                             int neighbours, double min_baseline_ratio);

// The keyframe's points projected into its first-order (`neighbours` best covisible) and
// second-order (5 best of each) neighbours, and their points into it: a point landing on a
// matching feature is added to it or merged with the point it has. Updates the touched points
// and the keyframe's covisibility. Returns the points fused or added.
int FuseWithNeighbours(Map* map, KeyframeId keyframe, const ViewGeometry& geometry, int neighbours);

}  // namespace stitch
