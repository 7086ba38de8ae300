#include "stitch/mapping/culling.h"

#include "stitch/estimators/pose_optimizer.h"

namespace stitch {

int RecentPoints::Cull(Map* map, KeyframeId keyframe, int keyframes_processed, const ViewGeometry& geometry,
                       double min_found_ratio, int min_observations) {
  // Recent points predicted in the new keyframe count as visible, and as found when it observes them.
  const Keyframe* kf = map->FindKeyframe(keyframe);
  int culled = 0;
  std::deque<Watched> kept;
  for (const Watched& recent : points_) {
    MapPoint* point = map->FindPoint(recent.id);
    if (!point) continue;
    if (kf && !point->observations.count(keyframe)) {
      PointInView view;
      if (geometry.InView(*point, kf->cam_from_world, &view)) ++point->visible;
    } else if (kf) {
      ++point->visible;
      ++point->found;
    }
    const int age = keyframes_processed - recent.created_at;
    if (point->FoundRatio() < min_found_ratio ||
        (age >= 2 && static_cast<int>(point->observations.size()) <= min_observations)) {
      map->RemovePoint(recent.id);
      ++culled;
    } else if (age < 3) {
      kept.push_back(recent);
    }
  }
  points_ = std::move(kept);
  return culled;
}

std::vector<CulledKeyframe> CullRedundantKeyframes(Map* map, KeyframeId keyframe, KeyframeId keep, double redundancy,
                                                   bool keep_observations) {
  std::vector<CulledKeyframe> culled;
  const Keyframe* kf = map->FindKeyframe(keyframe);
  if (!kf) return culled;
  std::vector<KeyframeId> neighbours;
  for (const auto& [weight, other] : kf->ordered) neighbours.push_back(other);
  constexpr int kRedundantObservers = 3;
  for (KeyframeId candidate : neighbours) {
    if (candidate == keep || candidate == keyframe) continue;
    const Keyframe* c = map->FindKeyframe(candidate);
    if (!c) continue;
    int points = 0, redundant = 0;
    for (size_t i = 0; i < c->points.size(); ++i) {
      const MapPoint* point = c->points[i].valid() ? map->FindPoint(c->points[i]) : nullptr;
      if (!point) continue;
      ++points;
      if (static_cast<int>(point->observations.size()) <= kRedundantObservers) continue;
      const int level = c->keypoints[i].octave;
      int observers = 0;
      for (const auto& [other, feature] : point->observations) {
        if (other == candidate) continue;
        const Keyframe* o = map->FindKeyframe(other);
        if (o && o->keypoints[feature].octave <= level + 1 && ++observers >= kRedundantObservers) break;
      }
      if (observers >= kRedundantObservers) ++redundant;
    }
    if (points > 0 && redundant > redundancy * points) {
      CulledKeyframe record;
      record.id = candidate;
      record.frame_index = c->frame_index;
      record.t_ns = c->t_ns;
      record.cam_from_world = c->cam_from_world;
      record.parent = c->parent;
      const Keyframe* parent = map->FindKeyframe(c->parent);
      record.cam_from_parent = parent ? c->cam_from_world * parent->cam_from_world.Inverse() : c->cam_from_world;
      if (!parent) record.parent = KeyframeId();
      for (size_t i = 0; keep_observations && i < c->points.size(); ++i) {
        if (c->points[i].valid() && map->FindPoint(c->points[i])) {
          record.observations.push_back({c->points[i], c->undistorted[i].cast<float>(), c->keypoints[i].octave});
        }
      }
      culled.push_back(std::move(record));
      map->RemoveKeyframe(candidate);
    }
  }
  return culled;
}

Rigid3d PoseOnRefinedMap(const Map& map, const CulledKeyframe& culled, const Rigid3d& cam_from_world,
                         const ViewGeometry& geometry, int min_inliers) {
  // Its relative pose to its parent is the one local bundle adjustment had reached when it was
  // culled (in a young map, sometimes few points' worth); its features place it as the map is now.
  const std::vector<float>& inverse_sigma2 = geometry.pyramid.inverse_sigma2;
  std::vector<PoseObservation> observations;
  observations.reserve(culled.observations.size());
  for (const CulledObservation& o : culled.observations) {
    const MapPoint* point = map.FindPoint(o.point);
    if (!point || o.octave < 0 || o.octave >= static_cast<int>(inverse_sigma2.size())) continue;
    observations.push_back({o.undistorted.cast<double>(), point->position, inverse_sigma2[o.octave]});
  }
  if (observations.size() < 3 || static_cast<int>(observations.size()) < min_inliers) return cam_from_world;
  const PoseOptimizerResult optimized = OptimizePose(observations, cam_from_world, geometry.intrinsics);
  if (!optimized.converged || optimized.num_inliers < min_inliers ||
      2 * optimized.num_inliers < static_cast<int>(observations.size())) {
    return cam_from_world;
  }
  return optimized.cam_from_world;
}

}  // namespace stitch
