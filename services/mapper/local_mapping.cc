#include "services/mapper/local_mapping.h"

#include <algorithm>
#include <cmath>
#include <set>
#include <unordered_map>

#include "stitch/estimators/triangulation.h"
#include "stitch/map/matcher.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "stitch/util/options.h"
#include "stitch/util/time.h"

namespace stitch {
namespace {

// First pyramid-level point index the mapper gives out; the tracker's initial map uses lower ones.
constexpr uint32_t kMapperPointIndexBase = 1u << 24;
constexpr int kDirectIndexLevel = 2;

}  // namespace

bool MappingOptions::Check(std::string* why) const {
  auto fail = [&](const std::string& m) { if (why) *why = m; return false; };
  if (triangulation_neighbours < 1 || fuse_neighbours < 0) return fail("mapper: neighbour counts must be positive");
  if (!(min_baseline_ratio >= 0)) return fail("mapper.min_baseline_ratio must be >= 0");
  if (!(point_min_found_ratio >= 0 && point_min_found_ratio <= 1)) return fail("mapper.point_min_found_ratio must be in [0, 1]");
  if (point_min_observations < 2) return fail("mapper.point_min_observations must be >= 2");
  if (!(keyframe_redundancy > 0 && keyframe_redundancy <= 1)) return fail("mapper.keyframe_redundancy must be in (0, 1]");
  return local_bundle_adjustment.Check(why);
}

LocalMapping::LocalMapping(const MappingOptions& options, const Camera& camera, const OrbOptions& orb,
                           const Vocabulary* vocabulary)
    : options_(options),
      camera_(camera),
      intrinsics_(camera.Intrinsics()),
      pyramid_(ScalePyramid::From(orb)),
      undistorter_(camera),
      vocabulary_(vocabulary) {
  CheckOptions(options_, "mapper");
  if (!vocabulary_ || vocabulary_->empty()) throw Error("LocalMapping needs a vocabulary");
}

std::optional<SubmapId> LocalMapping::CloseSubmap() {
  if (!map_) return std::nullopt;
  const SubmapId id = map_->id();
  closed_maps_.push_back(std::move(map_));
  recent_points_.clear();
  first_keyframe_ = KeyframeId();
  return id;
}

MappingReport LocalMapping::ProcessKeyframe(Keyframe keyframe, const std::vector<MapPoint>& new_points) {
  const Stopwatch clock;
  MappingReport report;
  report.keyframe = keyframe.id;
  const SubmapId submap = SubmapOf(keyframe.id);
  if (!map_ || map_->id() != submap) {
    // A new keyframe of a closed submap reopens it (the tracker relocalized there); a copy of
    // one it already holds is dropped.
    const auto find_closed = [&]() {
      return std::find_if(closed_maps_.begin(), closed_maps_.end(), [&](const auto& m) { return m->id() == submap; });
    };
    const bool was_closed = find_closed() != closed_maps_.end();
    if (was_closed && (*find_closed())->FindKeyframe(keyframe.id)) return report;
    if (map_) report.closed_submap = CloseSubmap();
    if (was_closed) {
      const auto closed = find_closed();
      map_ = std::move(*closed);
      closed_maps_.erase(closed);
      report.reopened_submap = submap;
      first_keyframe_ = KeyframeId();
      for (const auto& [id, k] : map_->keyframes()) {
        if (!first_keyframe_.valid() || id < first_keyframe_) first_keyframe_ = id;
      }
    }
  }
  if (!map_) {
    map_ = std::make_unique<Map>(submap, pyramid_, kMapperPointIndexBase);
    map_->EnableRemovalJournal();
    first_keyframe_ = keyframe.id;
  }
  if (map_->FindKeyframe(keyframe.id)) return report;  // a re-sent keyframe
  const KeyframeId id = keyframe.id;
  InsertKeyframe(std::move(keyframe), new_points);
  report.culled_points = CullRecentPoints(id);
  report.new_points = TriangulateNewPoints(id);
  report.fused = FuseWithNeighbours(id);
  if (map_->num_keyframes() > 2) {
    report.bundle_adjustment = LocalBundleAdjustment(map_.get(), id, intrinsics_, options_.local_bundle_adjustment);
  }
  if (options_.cull_keyframes) report.culled_keyframes = CullKeyframes(id);
  ++keyframes_processed_;
  report.milliseconds = clock.ElapsedMs();
  return report;
}

void LocalMapping::InsertKeyframe(Keyframe keyframe, const std::vector<MapPoint>& new_points) {
  // Keypoint geometry is recomputed here: a keyframe from the bus carries only raw keypoints.
  if (keyframe.undistorted.size() != keyframe.keypoints.size()) {
    keyframe.undistorted.clear();
    for (const auto& k : keyframe.keypoints) keyframe.undistorted.push_back(undistorter_.Undistort(k.pt.x, k.pt.y));
  }
  keyframe.grid = FeatureGrid(keyframe.undistorted, undistorter_);
  if (keyframe.bow.empty()) keyframe.bow = vocabulary_->Transform(keyframe.descriptors, &keyframe.bow_features, kDirectIndexLevel);
  for (const MapPoint& point : new_points) {
    if (!map_->FindPoint(point.id)) map_->AddPoint(point);
  }
  const KeyframeId id = keyframe.id;
  map_->AddKeyframe(std::move(keyframe));
  Keyframe* inserted = map_->FindKeyframe(id);
  // Observations from the tracker's associations; update the points' appearance and geometry.
  for (MapPointId p : inserted->points) {
    if (!p.valid()) continue;
    map_->UpdatePointAppearance(p);
    map_->UpdatePointGeometry(p);
  }
  for (const MapPoint& point : new_points) recent_points_.push_back({point.id, keyframes_processed_});
  map_->UpdateConnections(id);
}

int LocalMapping::CullRecentPoints(KeyframeId keyframe) {
  // Recent points predicted in the new keyframe count as visible, and as found when it observes them.
  const Keyframe* kf = map_->FindKeyframe(keyframe);
  int culled = 0;
  std::deque<RecentPoint> kept;
  for (const RecentPoint& recent : recent_points_) {
    MapPoint* point = map_->FindPoint(recent.id);
    if (!point) continue;
    if (kf && !point->observations.count(keyframe)) {
      PointInView view;
      if (PredictInView(*point, kf->cam_from_world, intrinsics_, undistorter_.min_x(), undistorter_.min_y(),
                        undistorter_.max_x(), undistorter_.max_y(), pyramid_, &view)) {
        ++point->visible;
      }
    } else if (kf) {
      ++point->visible;
      ++point->found;
    }
    const int age = keyframes_processed_ - recent.created_at;
    if (point->FoundRatio() < options_.point_min_found_ratio ||
        (age >= 2 && static_cast<int>(point->observations.size()) <= options_.point_min_observations)) {
      map_->RemovePoint(recent.id);
      ++culled;
    } else if (age < 3) {
      kept.push_back(recent);
    }
  }
  recent_points_ = std::move(kept);
  return culled;
}

int LocalMapping::TriangulateNewPoints(KeyframeId keyframe) {
  Keyframe* kf1 = map_->FindKeyframe(keyframe);
  const std::vector<KeyframeId> neighbours = map_->BestCovisible(keyframe, options_.triangulation_neighbours);
  const double ratio_factor = 1.5 * pyramid_.scale_factor;
  int created = 0;
  for (KeyframeId neighbour : neighbours) {
    Keyframe* kf2 = map_->FindKeyframe(neighbour);
    if (!kf2) continue;
    const double baseline = (kf1->Centre() - kf2->Centre()).norm();
    const double median_depth = map_->MedianDepth(neighbour);
    if (median_depth <= 0 || baseline / median_depth < options_.min_baseline_ratio) continue;
    const Eigen::Matrix3d f21 = FundamentalMatrix(kf1->cam_from_world, kf2->cam_from_world, intrinsics_);
    const auto pairs = SearchForTriangulation(*kf1, *kf2, f21, intrinsics_, pyramid_);
    const Eigen::Matrix3d r1 = kf1->cam_from_world.RotationMatrix().transpose();
    const Eigen::Matrix3d r2 = kf2->cam_from_world.RotationMatrix().transpose();
    for (const auto& [i, j] : pairs) {
      if (kf1->points[i].valid() || kf2->points[j].valid()) continue;
      const Eigen::Vector2d n1 = intrinsics_.Normalize(kf1->undistorted[i]);
      const Eigen::Vector2d n2 = intrinsics_.Normalize(kf2->undistorted[j]);
      const Eigen::Vector3d ray1 = r1 * n1.homogeneous(), ray2 = r2 * n2.homogeneous();
      const double cos_rays = ray1.dot(ray2) / (ray1.norm() * ray2.norm());
      if (cos_rays <= 0 || cos_rays >= 0.9998) continue;
      const auto x = TriangulateDlt(kf1->cam_from_world, n1, kf2->cam_from_world, n2);
      if (!x) continue;
      const Eigen::Vector3d in1 = kf1->cam_from_world * *x, in2 = kf2->cam_from_world * *x;
      if (in1.z() <= 0 || in2.z() <= 0) continue;
      const int level1 = kf1->keypoints[i].octave, level2 = kf2->keypoints[j].octave;
      if ((intrinsics_.Project(in1) - kf1->undistorted[i]).squaredNorm() > 5.991 * pyramid_.sigma2[level1]) continue;
      if ((intrinsics_.Project(in2) - kf2->undistorted[j]).squaredNorm() > 5.991 * pyramid_.sigma2[level2]) continue;
      // Scale consistency: the distance ratio must agree with the pyramid levels seen at.
      const double distance1 = (*x - kf1->Centre()).norm(), distance2 = (*x - kf2->Centre()).norm();
      if (distance1 <= 0 || distance2 <= 0) continue;
      const double ratio_distance = distance2 / distance1;
      const double ratio_octave = pyramid_.scale[level1] / pyramid_.scale[level2];
      if (ratio_distance * ratio_factor < ratio_octave || ratio_distance > ratio_octave * ratio_factor) continue;
      MapPoint point;
      point.id = map_->NewPointId();
      point.position = *x;
      point.reference_keyframe = keyframe;
      point.first_keyframe = keyframe;
      map_->AddPoint(point);
      map_->AddObservation(keyframe, i, point.id);
      map_->AddObservation(neighbour, j, point.id);
      map_->UpdatePointAppearance(point.id);
      map_->UpdatePointGeometry(point.id);
      recent_points_.push_back({point.id, keyframes_processed_});
      ++created;
    }
  }
  return created;
}

int LocalMapping::FuseWithNeighbours(KeyframeId keyframe) {
  // First and second order neighbours.
  std::vector<KeyframeId> targets;
  std::set<KeyframeId> seen{keyframe};
  for (KeyframeId n : map_->BestCovisible(keyframe, options_.fuse_neighbours)) {
    if (seen.insert(n).second) targets.push_back(n);
  }
  const size_t first_order = targets.size();
  for (size_t t = 0; t < first_order; ++t) {
    for (KeyframeId n2 : map_->BestCovisible(targets[t], 5)) {
      if (seen.insert(n2).second) targets.push_back(n2);
    }
  }
  int fused = 0;
  // The keyframe's points into the neighbours...
  std::vector<MapPointId> own;
  for (MapPointId p : map_->FindKeyframe(keyframe)->points) {
    if (p.valid()) own.push_back(p);
  }
  for (KeyframeId target : targets) fused += Fuse(map_.get(), target, own, intrinsics_);
  // ...and the neighbours' points into the keyframe.
  std::set<MapPointId> theirs;
  for (KeyframeId target : targets) {
    if (const Keyframe* kf = map_->FindKeyframe(target)) {
      for (MapPointId p : kf->points) {
        if (p.valid()) theirs.insert(p);
      }
    }
  }
  fused += Fuse(map_.get(), keyframe, std::vector<MapPointId>(theirs.begin(), theirs.end()), intrinsics_);
  for (MapPointId p : map_->FindKeyframe(keyframe)->points) {
    if (!p.valid() || !map_->FindPoint(p)) continue;
    map_->UpdatePointAppearance(p);
    map_->UpdatePointGeometry(p);
  }
  map_->UpdateConnections(keyframe);
  return fused;
}

std::vector<KeyframeId> LocalMapping::CullKeyframes(KeyframeId keyframe) {
  std::vector<KeyframeId> culled;
  const Keyframe* kf = map_->FindKeyframe(keyframe);
  if (!kf) return culled;
  std::vector<KeyframeId> neighbours;
  for (const auto& [weight, other] : kf->ordered) neighbours.push_back(other);
  constexpr int kRedundantObservers = 3;
  for (KeyframeId candidate : neighbours) {
    if (candidate == first_keyframe_ || candidate == keyframe) continue;
    const Keyframe* c = map_->FindKeyframe(candidate);
    if (!c) continue;
    int points = 0, redundant = 0;
    for (size_t i = 0; i < c->points.size(); ++i) {
      const MapPoint* point = c->points[i].valid() ? map_->FindPoint(c->points[i]) : nullptr;
      if (!point) continue;
      ++points;
      if (static_cast<int>(point->observations.size()) <= kRedundantObservers) continue;
      const int level = c->keypoints[i].octave;
      int observers = 0;
      for (const auto& [other, feature] : point->observations) {
        if (other == candidate) continue;
        const Keyframe* o = map_->FindKeyframe(other);
        if (o && o->keypoints[feature].octave <= level + 1 && ++observers >= kRedundantObservers) break;
      }
      if (observers >= kRedundantObservers) ++redundant;
    }
    if (points > 0 && redundant > options_.keyframe_redundancy * points) {
      CulledRecord record;
      record.keyframe = {candidate, c->frame_index, c->t_ns, c->cam_from_world};
      record.parent = c->parent;
      const Keyframe* parent = map_->FindKeyframe(c->parent);
      record.cam_from_parent = parent ? c->cam_from_world * parent->cam_from_world.Inverse() : c->cam_from_world;
      if (!parent) record.parent = KeyframeId();
      culled_.push_back(record);
      map_->RemoveKeyframe(candidate);
      culled.push_back(candidate);
    }
  }
  return culled;
}

std::vector<CulledKeyframe> LocalMapping::CulledKeyframePoses() const {
  std::unordered_map<KeyframeId, const CulledRecord*> by_id;
  for (const auto& record : culled_) by_id[record.keyframe.id] = &record;
  const auto living = [&](KeyframeId id) -> const Keyframe* {
    if (map_) {
      if (const Keyframe* kf = map_->FindKeyframe(id)) return kf;
    }
    for (const auto& closed : closed_maps_) {
      if (const Keyframe* kf = closed->FindKeyframe(id)) return kf;
    }
    return nullptr;
  };
  std::vector<CulledKeyframe> result;
  for (const auto& record : culled_) {
    // Walk up through culled parents to a living keyframe, composing the relative poses.
    Rigid3d cam_from_ancestor = record.cam_from_parent;
    KeyframeId ancestor = record.parent;
    Rigid3d cam_from_world = record.keyframe.cam_from_world;
    for (int depth = 0; depth < 1000 && ancestor.valid(); ++depth) {
      if (const Keyframe* kf = living(ancestor)) {
        cam_from_world = cam_from_ancestor * kf->cam_from_world;
        break;
      }
      const auto it = by_id.find(ancestor);
      if (it == by_id.end()) break;
      if (!it->second->parent.valid()) {
        cam_from_world = cam_from_ancestor * it->second->cam_from_parent;
        break;
      }
      cam_from_ancestor = cam_from_ancestor * it->second->cam_from_parent;
      ancestor = it->second->parent;
    }
    CulledKeyframe k = record.keyframe;
    k.cam_from_world = cam_from_world;
    result.push_back(k);
  }
  return result;
}

LocalMapUpdate LocalMapping::MakeUpdate(KeyframeId keyframe, int queued_keyframes) {
  if (!map_) return {};
  return MakeLocalMapUpdate(map_.get(), keyframe, ++revision_, queued_keyframes);
}

SubmapUpdate LocalMapping::MakeSubmapUpdate(KeyframeId keyframe, const LocalMapUpdate& changes) const {
  if (!map_) return {};
  return MakeKeyframeSubmapUpdate(*map_, keyframe, camera_, changes);
}

SubmapUpdate LocalMapping::MakeFinalSubmapUpdate(SubmapId submap) {
  for (const auto& closed : closed_maps_) {
    if (closed->id() == submap) return MakeFullSubmapUpdate(closed.get(), ++revision_, /*closed=*/true);
  }
  return {};
}

SubmapUpdate LocalMapping::MakeResendUpdate(SubmapId submap, const std::vector<KeyframeId>& keyframes,
                                            bool full_state) {
  Map* found = map_ && map_->id() == submap ? map_.get() : nullptr;
  for (const auto& closed : closed_maps_) {
    if (closed->id() == submap) found = closed.get();
  }
  if (!found) return {};
  const bool closed = found != map_.get();
  // A closed submap goes in full: its final state is what settles it at the receiver, and a
  // partial update marked closed would let the receiver think it had it.
  full_state = full_state || closed;
  LocalMapUpdate changes;
  SubmapUpdate update;
  if (full_state) {
    update = MakeFullSubmapUpdate(found, ++revision_, closed);
  } else {
    changes.revision = ++revision_;
    std::set<MapPointId> points;
    for (KeyframeId id : keyframes) {
      const Keyframe* keyframe = found->FindKeyframe(id);
      if (!keyframe) continue;
      changes.associations.push_back({id, keyframe->points});
      for (MapPointId p : keyframe->points) {
        if (p.valid() && found->FindPoint(p)) points.insert(p);
      }
    }
    for (MapPointId p : points) {
      MapPoint copy = *found->FindPoint(p);
      copy.observations.clear();
      changes.points.push_back(std::move(copy));
    }
  }
  for (KeyframeId id : keyframes) {
    if (!found->FindKeyframe(id)) continue;  // culled since: the manifest no longer lists it
    SubmapUpdate one = MakeKeyframeSubmapUpdate(*found, id, camera_, changes);
    if (!full_state && update.new_keyframes.empty()) {
      update = one;  // carries `changes` and the manifest
      update.closed = closed;
      continue;
    }
    for (Keyframe& keyframe : one.new_keyframes) update.new_keyframes.push_back(std::move(keyframe));
  }
  update.camera = camera_;
  return update;
}

SubmapUpdate LocalMapping::MakeManifestUpdate() {
  SubmapUpdate update;
  if (!map_ || map_->num_keyframes() == 0) return update;
  update.submap = map_->id();
  update.revision = ++revision_;
  update.camera = camera_;
  update.changes.submap = map_->id();
  update.changes.revision = update.revision;
  for (const auto& [id, keyframe] : map_->keyframes()) update.manifest.push_back(id);
  std::sort(update.manifest.begin(), update.manifest.end());
  return update;
}

}  // namespace stitch
