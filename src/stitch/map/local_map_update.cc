#include "stitch/map/local_map_update.h"

#include <set>

namespace stitch {

LocalMapUpdate MakeLocalMapUpdate(Map* map, KeyframeId keyframe, int revision, int queued_keyframes) {
  LocalMapUpdate update;
  update.submap = map->id();
  update.revision = revision;
  update.last_keyframe = keyframe;
  update.queued_keyframes = queued_keyframes;
  std::vector<KeyframeId> window{keyframe};
  if (const Keyframe* kf = map->FindKeyframe(keyframe)) {
    for (const auto& [weight, other] : kf->ordered) window.push_back(other);
  }
  std::set<MapPointId> points;
  for (KeyframeId id : window) {
    const Keyframe* kf = map->FindKeyframe(id);
    if (!kf) continue;
    update.keyframe_poses.push_back({id, kf->cam_from_world});
    update.associations.push_back({id, kf->points});
    for (MapPointId p : kf->points) {
      if (p.valid()) points.insert(p);
    }
  }
  for (MapPointId p : points) {
    if (const MapPoint* point = map->FindPoint(p)) {
      MapPoint copy = *point;
      copy.observations.clear();
      update.points.push_back(std::move(copy));
    }
  }
  update.removed_points = map->TakeRemovedPoints();
  update.removed_keyframes = map->TakeRemovedKeyframes();
  return update;
}

LocalMapUpdate MakeNewPointsUpdate(const Map& map, KeyframeId keyframe, const std::vector<MapPointId>& created,
                                   int revision) {
  LocalMapUpdate update;
  update.submap = map.id();
  update.revision = revision;
  std::set<KeyframeId> observers{keyframe};
  for (MapPointId p : created) {
    const MapPoint* point = map.FindPoint(p);
    if (!point) continue;
    for (const auto& [observer, feature] : point->observations) observers.insert(observer);
    MapPoint copy = *point;
    copy.observations.clear();
    update.points.push_back(std::move(copy));
  }
  for (KeyframeId id : observers) {
    if (const Keyframe* observer = map.FindKeyframe(id)) update.associations.push_back({id, observer->points});
  }
  return update;
}

std::vector<KeyframeId> ApplyLocalMapUpdate(const LocalMapUpdate& update, Map* map) {
  std::vector<KeyframeId> changed;
  if (update.submap != map->id()) return changed;
  for (KeyframeId id : update.removed_keyframes) map->RemoveKeyframe(id);
  for (MapPointId id : update.removed_points) map->RemovePoint(id);
  for (const MapPoint& incoming : update.points) {
    if (MapPoint* existing = map->FindPoint(incoming.id)) {
      existing->position = incoming.position;
      existing->descriptor = incoming.descriptor;
      existing->normal = incoming.normal;
      existing->min_distance = incoming.min_distance;
      existing->max_distance = incoming.max_distance;
    } else {
      map->AddPoint(incoming);
    }
  }
  for (const auto& [id, points] : update.associations) {
    Keyframe* keyframe = map->FindKeyframe(id);
    if (!keyframe || points.size() != keyframe->points.size()) continue;
    bool any = false;
    for (size_t i = 0; i < points.size(); ++i) {
      const MapPointId now = keyframe->points[i];
      const MapPointId wanted = points[i].valid() && map->FindPoint(points[i]) ? points[i] : MapPointId();
      if (now == wanted) continue;
      if (now.valid()) map->EraseObservation(id, now, 0);  // the mapper decides which points die
      if (wanted.valid()) map->AddObservation(id, static_cast<int>(i), wanted);
      any = true;
    }
    if (any) changed.push_back(id);
  }
  for (const auto& [id, pose] : update.keyframe_poses) {
    if (Keyframe* keyframe = map->FindKeyframe(id)) keyframe->cam_from_world = pose;
  }
  for (KeyframeId id : changed) map->UpdateConnections(id);
  return changed;
}

std::vector<LocalMapUpdate> SplitLocalMapUpdate(const LocalMapUpdate& update, size_t max_bytes) {
  // Sizes as keyframe_association_t and map_point_t encode them (plus a little slack).
  constexpr size_t kPointBytes = 72, kPoseBytes = 68, kHeaderBytes = 120;
  std::vector<LocalMapUpdate> parts;
  LocalMapUpdate part;
  size_t bytes = kHeaderBytes;
  const auto start_part = [&]() {
    part = LocalMapUpdate();
    part.submap = update.submap;
    part.revision = update.revision;
    part.last_keyframe = update.last_keyframe;
    part.queued_keyframes = update.queued_keyframes;
    bytes = kHeaderBytes;
  };
  const auto flush = [&]() {
    parts.push_back(std::move(part));
    start_part();
  };
  start_part();
  // Removals and poses are small: the first part carries them all.
  part.removed_points = update.removed_points;
  part.removed_keyframes = update.removed_keyframes;
  part.keyframe_poses = update.keyframe_poses;
  bytes += 4 * update.removed_points.size() + 8 * update.removed_keyframes.size() +
           kPoseBytes * update.keyframe_poses.size();
  // Points before associations, so each association finds its points in an earlier part or
  // its own (parts are applied in order; a lost part is repaired by the next update).
  for (const MapPoint& point : update.points) {
    if (bytes + kPointBytes > max_bytes && (bytes > kHeaderBytes)) flush();
    part.points.push_back(point);
    bytes += kPointBytes;
  }
  for (const auto& association : update.associations) {
    const size_t size = 12 + 4 * association.second.size();
    if (bytes + size > max_bytes && bytes > kHeaderBytes) flush();
    part.associations.push_back(association);
    bytes += size;
  }
  flush();
  return parts;
}

}  // namespace stitch
