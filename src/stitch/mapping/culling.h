#pragma once
// The mapper's culling stages (ORB-SLAM2's local mapping steps 2 and 6): new points that do not
// prove themselves over the next keyframes are removed, and keyframes whose points are nearly all
// seen by other keyframes (at the same or a finer scale) are removed as redundant. Plain code
// over one map; the caller owns the map.

#include <deque>
#include <vector>

#include "stitch/map/map.h"
#include "stitch/map/view_geometry.h"

namespace stitch {

// Points made in the last keyframes, watched until they prove themselves: each new keyframe
// that predicts a point in view counts as a chance to see it, and as a find when it observes it.
// A point found in fewer than `min_found_ratio` of its chances, or still observed by at most
// `min_observations` keyframes two keyframes after it was made, is removed from the map; one
// that survives three keyframes is no longer watched.
class RecentPoints {
 public:
  // `created_at`: keyframes processed when the point was made.
  void Add(MapPointId id, int created_at) { points_.push_back({id, created_at}); }
  // After `keyframe` (the `keyframes_processed`-th) entered `map`: counts and removes. Returns
  // the points removed.
  int Cull(Map* map, KeyframeId keyframe, int keyframes_processed, const ViewGeometry& geometry, double min_found_ratio,
           int min_observations);
  void Clear() { points_.clear(); }
  size_t size() const { return points_.size(); }

 private:
  struct Watched {
    MapPointId id;
    int created_at;
  };
  std::deque<Watched> points_;
};

// One of a culled keyframe's features that observed a point when it was culled.
struct CulledObservation {
  MapPointId point;
  Eigen::Vector2f undistorted;  // pixels
  int octave = 0;
};

// A keyframe removed as redundant, and what places it later: its parent in the spanning tree
// (invalid: `cam_from_parent` is cam_from_world) and its pose relative to that parent; and the
// points it observed, to pose it again against the refined map (LocalMapping::CulledKeyframePoses).
struct CulledKeyframe {
  KeyframeId id;
  int frame_index = -1;
  int64_t t_ns = 0;
  Rigid3d cam_from_world;  // when culled
  KeyframeId parent;
  Rigid3d cam_from_parent;
  std::vector<CulledObservation> observations;
};

// The covisible keyframes of `keyframe` (never `keep`, nor `keyframe` itself) of which more than
// `redundancy` of the points are seen by at least 3 other keyframes at the same or a finer
// scale are removed from `map`. Returns them, in the order removed, with the points each observed
// where `keep_observations` (to pose it again later: PoseOnRefinedMap).
std::vector<CulledKeyframe> CullRedundantKeyframes(Map* map, KeyframeId keyframe, KeyframeId keep, double redundancy,
                                                   bool keep_observations = true);

// A culled keyframe's pose against the points of `map` it observed, refined since it was culled
// (by the keyframes that made it redundant), found from `cam_from_world` (its pose through its
// parent). Returns `cam_from_world` where fewer than `min_inliers` of those points are left or
// agree, or fewer than half of them agree.
Rigid3d PoseOnRefinedMap(const Map& map, const CulledKeyframe& culled, const Rigid3d& cam_from_world,
                         const ViewGeometry& geometry, int min_inliers = 30);

}  // namespace stitch
