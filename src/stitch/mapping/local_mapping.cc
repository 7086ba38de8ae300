#include "stitch/mapping/local_mapping.h"

#include <algorithm>
#include <set>
#include <unordered_map>

#include "stitch/mapping/new_points.h"
#include "stitch/util/error.h"
#include "stitch/util/options.h"
#include "stitch/util/time.h"

namespace stitch {
namespace {

// First pyramid-level point index the mapper gives out; the tracker's initial map uses lower ones.
constexpr uint32_t kMapperPointIndexBase = 1u << 24;

}  // namespace

LocalMapping::LocalMapping(const MappingOptions& options, const Camera& camera, const OrbOptions& orb,
                           const Vocabulary* vocabulary)
    : options_(options), geometry_(camera, ScalePyramid::From(orb)), vocabulary_(vocabulary) {
  CheckOptions(options_, "mapper");
  if (!vocabulary_ || vocabulary_->empty()) throw Error("LocalMapping needs a vocabulary");
}

std::optional<SubmapId> LocalMapping::CloseSubmap() {
  if (!map_) return std::nullopt;
  const SubmapId id = map_->id();
  closed_maps_.push_back(std::move(map_));
  recent_points_.Clear();
  first_keyframe_ = KeyframeId();
  return id;
}

MappedKeyframe LocalMapping::MapKeyframe(Keyframe keyframe, const std::vector<MapPoint>& new_points,
                                         const MappingHooks& hooks) {
  MappedKeyframe mapped;
  mapped.report = ProcessKeyframe(std::move(keyframe), new_points, hooks);
  if (mapped.report.closed_submap) mapped.closed_final = MakeFinalSubmapUpdate(*mapped.report.closed_submap);
  mapped.for_tracker = MakeUpdate(mapped.report.keyframe, 0);
  // A keyframe sent again (its update to the tracker was lost, or the mapper was slow to answer)
  // is answered to the tracker; the merger has it already, or asks for what it lacks.
  if (!mapped.report.duplicate) mapped.for_merger = MakeSubmapUpdate(mapped.report.keyframe, mapped.for_tracker);
  return mapped;
}

MappingReport LocalMapping::ProcessKeyframe(Keyframe keyframe, const std::vector<MapPoint>& new_points,
                                            const MappingHooks& hooks) {
  const Interruption& next_waiting = hooks.next_waiting;
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
    if (was_closed && (*find_closed())->FindKeyframe(keyframe.id)) {
      report.duplicate = true;
      return report;
    }
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
    map_ = std::make_unique<Map>(submap, geometry_.pyramid, kMapperPointIndexBase);
    map_->EnableRemovalJournal();
    first_keyframe_ = keyframe.id;
  }
  if (map_->FindKeyframe(keyframe.id)) {  // a re-sent keyframe
    report.duplicate = true;
    return report;
  }
  const KeyframeId id = keyframe.id;
  MappingStageTimes& times = report.stage_ms;
  Stopwatch stage;
  const auto lap = [&stage](double* ms) {
    *ms = stage.ElapsedMs();
    stage.Restart();
  };
  InsertKeyframe(std::move(keyframe), new_points);
  lap(&times.insert);
  report.culled_points = recent_points_.Cull(map_.get(), id, keyframes_processed_, geometry_,
                                             options_.point_min_found_ratio, options_.point_min_observations);
  lap(&times.cull_points);
  const std::vector<MapPointId> created =
      TriangulateNewPoints(map_.get(), id, geometry_, options_.triangulation_neighbours, options_.min_baseline_ratio);
  for (MapPointId point : created) recent_points_.Add(point, keyframes_processed_);
  report.new_points = static_cast<int>(created.size());
  lap(&times.triangulate);
  if (hooks.new_points_made && !created.empty())
    hooks.new_points_made(MakeNewPointsUpdate(*map_, id, created, ++revision_));
  // The first keyframe of a map is never left to the next one: it has nothing to be fused with
  // or adjusted against, and the tracker sends it together with the second (its
  // initialization), so leaving it would only depend on whether that one had arrived yet.
  if (map_->num_keyframes() > 1 && next_waiting && next_waiting()) {
    report.deferred = true;
    ++keyframes_processed_;
    report.milliseconds = clock.ElapsedMs();
    return report;
  }
  report.fused = FuseWithNeighbours(map_.get(), id, geometry_, options_.fuse_neighbours);
  lap(&times.fuse);
  if (map_->num_keyframes() > 2) {
    report.bundle_adjustment =
        LocalBundleAdjustment(map_.get(), id, geometry_.intrinsics, options_.local_bundle_adjustment, next_waiting);
  }
  lap(&times.bundle_adjustment);
  if (options_.cull_keyframes && !report.bundle_adjustment.interrupted) {
    for (CulledKeyframe& culled : CullRedundantKeyframes(map_.get(), id, first_keyframe_, options_.keyframe_redundancy,
                                                         options_.repose_culled_keyframes)) {
      report.culled_keyframes.push_back(culled.id);
      culled_.push_back(std::move(culled));
    }
  }
  lap(&times.cull_keyframes);
  ++keyframes_processed_;
  report.milliseconds = clock.ElapsedMs();
  return report;
}

void LocalMapping::InsertKeyframe(Keyframe keyframe, const std::vector<MapPoint>& new_points) {
  // Keypoint geometry is recomputed here: a keyframe from the bus carries only raw keypoints.
  if (keyframe.undistorted.size() != keyframe.keypoints.size()) {
    keyframe.undistorted.clear();
    for (const auto& k : keyframe.keypoints)
      keyframe.undistorted.push_back(geometry_.undistorter.Undistort(k.pt.x, k.pt.y));
  }
  keyframe.grid = FeatureGrid(keyframe.undistorted, geometry_.undistorter);
  if (keyframe.bow.empty()) keyframe.bow = vocabulary_->Transform(keyframe.descriptors, &keyframe.bow_features);
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
  for (const MapPoint& point : new_points) recent_points_.Add(point.id, keyframes_processed_);
  map_->UpdateConnections(id);
}

LocalMapping::Released LocalMapping::ReleaseClosed(SubmapId submap) {
  Released released;
  const auto it =
      std::find_if(closed_maps_.begin(), closed_maps_.end(), [&](const auto& m) { return m->id() == submap; });
  if (it == closed_maps_.end()) return released;
  released.culled = CulledKeyframePoses(submap);  // posed on the map while it is here
  culled_.erase(std::remove_if(culled_.begin(), culled_.end(),
                               [&](const CulledKeyframe& culled) { return SubmapOf(culled.id) == submap; }),
                culled_.end());
  released.map = std::move(*it);
  closed_maps_.erase(it);
  return released;
}

std::vector<CulledKeyframe> LocalMapping::CulledKeyframePoses(SubmapId submap) const {
  std::unordered_map<KeyframeId, const CulledKeyframe*> by_id;
  for (const auto& record : culled_) by_id[record.id] = &record;
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
  result.reserve(culled_.size());
  for (const auto& record : culled_) {
    if (submap.valid() && SubmapOf(record.id) != submap) continue;
    // Walk up through culled parents to a living keyframe, composing the relative poses.
    Rigid3d cam_from_ancestor = record.cam_from_parent;
    KeyframeId ancestor = record.parent;
    Rigid3d cam_from_world = record.cam_from_world;
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
    const Map* map = options_.repose_culled_keyframes ? FindSubmap(SubmapOf(record.id)) : nullptr;
    if (map) cam_from_world = PoseOnRefinedMap(*map, record, cam_from_world, geometry_);
    result.push_back({record.id, record.frame_index, record.t_ns, cam_from_world, record.parent, record.cam_from_parent,
                      /*observations=*/{}});
  }
  return result;
}

LocalMapUpdate LocalMapping::MakeUpdate(KeyframeId keyframe, int queued_keyframes) {
  if (!map_) return {};
  return MakeLocalMapUpdate(map_.get(), keyframe, ++revision_, queued_keyframes);
}

SubmapUpdate LocalMapping::MakeSubmapUpdate(KeyframeId keyframe, const LocalMapUpdate& changes) const {
  if (!map_) return {};
  return MakeKeyframeSubmapUpdate(*map_, keyframe, geometry_.camera, changes);
}

SubmapUpdate LocalMapping::MakeFinalSubmapUpdate(SubmapId submap) {
  for (const auto& closed : closed_maps_) {
    if (closed->id() == submap) return MakeFullSubmapUpdate(closed.get(), ++revision_, /*closed=*/true);
  }
  return {};
}

SubmapUpdate LocalMapping::MakeResendUpdate(SubmapId submap, const std::vector<KeyframeId>& keyframes,
                                            bool full_state) {
  Map* found = FindSubmap(submap);
  if (!found) return {};
  const bool closed = found != map_.get();
  // A closed submap's keyframes alone go without their points, as revision 0, older than any
  // state: a receiver takes the keyframes, and the points and associations they observe come
  // with the final state (it asks for that on its own). Sent with the final state each time, a
  // keyframe or two the link lost cost the submap's whole state again (1-2 MB, behind a link that
  // may carry 100 kB/s); with their points, a few keyframes at a time sent most points many times.
  const bool keyframes_alone = closed && !full_state;
  return MakeResendSubmapUpdate(found, geometry_.camera, keyframes, full_state, closed,
                                keyframes_alone ? 0 : ++revision_);
}

Map* LocalMapping::FindSubmap(SubmapId submap) const {
  if (map_ && map_->id() == submap) return map_.get();  // a reopened submap is no longer closed
  for (const auto& closed : closed_maps_) {
    if (closed->id() == submap) return closed.get();
  }
  return nullptr;
}

bool LocalMapping::Holds(KeyframeId keyframe) const {
  const Map* map = FindSubmap(SubmapOf(keyframe));
  return map && map->FindKeyframe(keyframe);
}

bool LocalMapping::Holds(SubmapId submap) const {
  return FindSubmap(submap) != nullptr;
}

SubmapUpdate LocalMapping::MakeManifestUpdate() {
  if (!map_ || map_->num_keyframes() == 0) return {};
  return MakeManifestSubmapUpdate(*map_, geometry_.camera, ++revision_);
}

}  // namespace stitch
