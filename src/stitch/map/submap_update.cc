#include "stitch/map/submap_update.h"

#include <algorithm>
#include <set>
#include <unordered_set>

namespace stitch {
namespace {

// A keyframe as it travels: features, descriptors, pose and associations, no caches.
Keyframe Transportable(const Keyframe& keyframe) {
  Keyframe k;
  k.id = keyframe.id;
  k.frame_index = keyframe.frame_index;
  k.t_ns = keyframe.t_ns;
  k.cam_from_world = keyframe.cam_from_world;
  k.keypoints = keyframe.keypoints;
  k.descriptors = keyframe.descriptors.clone();
  k.points = keyframe.points;
  return k;
}

}  // namespace

size_t KeyframeMessageBytes(const Keyframe& keyframe) {
  // keyframe_t: 42 bytes per feature and about 220 fixed (services/common/lcm_types_test.cc).
  return 42 * keyframe.keypoints.size() + 240;
}

SubmapUpdate MakeKeyframeSubmapUpdate(const Map& map, KeyframeId keyframe, const Camera& camera,
                                      const LocalMapUpdate& changes) {
  SubmapUpdate update;
  update.submap = map.id();
  update.revision = changes.revision;
  update.camera = camera;
  if (const Keyframe* k = map.FindKeyframe(keyframe)) update.new_keyframes.push_back(Transportable(*k));
  update.changes = changes;
  update.changes.submap = map.id();
  for (const auto& [id, k] : map.keyframes()) update.manifest.push_back(id);
  return update;
}

SubmapUpdate MakeResendSubmapUpdate(Map* map, const Camera& camera, const std::vector<KeyframeId>& keyframes,
                                    bool full_state, bool closed, int revision) {
  const bool keyframes_alone = closed && !full_state;
  LocalMapUpdate changes;
  SubmapUpdate update;
  if (full_state) {
    update = MakeFullSubmapUpdate(map, revision, closed);
  } else {
    changes.revision = revision;
    std::set<MapPointId> points;
    for (KeyframeId id : keyframes_alone ? std::vector<KeyframeId>() : keyframes) {
      const Keyframe* keyframe = map->FindKeyframe(id);
      if (!keyframe) continue;
      changes.associations.push_back({id, keyframe->points});
      for (MapPointId p : keyframe->points) {
        if (p.valid() && map->FindPoint(p)) points.insert(p);
      }
    }
    for (MapPointId p : points) {
      MapPoint copy = *map->FindPoint(p);
      copy.observations.clear();
      changes.points.push_back(std::move(copy));
    }
  }
  for (KeyframeId id : keyframes) {
    if (!map->FindKeyframe(id)) continue;  // culled since: the manifest no longer lists it
    SubmapUpdate one = MakeKeyframeSubmapUpdate(*map, id, camera, changes);
    if (!full_state && update.new_keyframes.empty()) {
      update = one;                         // carries `changes` and the manifest
      if (closed) update.manifest.clear();  // the final state's stands
      continue;
    }
    for (Keyframe& keyframe : one.new_keyframes) update.new_keyframes.push_back(std::move(keyframe));
  }
  update.camera = camera;
  return update;
}

SubmapUpdate MakeManifestSubmapUpdate(const Map& map, const Camera& camera, int revision) {
  SubmapUpdate update;
  if (map.num_keyframes() == 0) return update;
  update.submap = map.id();
  update.revision = revision;
  update.camera = camera;
  update.changes.submap = map.id();
  update.changes.revision = revision;
  for (const auto& [id, keyframe] : map.keyframes()) update.manifest.push_back(id);
  std::sort(update.manifest.begin(), update.manifest.end());
  return update;
}

SubmapUpdate MakeFullSubmapUpdate(Map* map, int revision, bool closed) {
  SubmapUpdate update;
  update.submap = map->id();
  update.revision = revision;
  update.closed = closed;
  update.full_state = true;
  LocalMapUpdate& changes = update.changes;
  changes.submap = map->id();
  changes.revision = revision;
  for (const auto& [id, keyframe] : map->keyframes()) {
    update.manifest.push_back(id);
    changes.keyframe_poses.push_back({id, keyframe.cam_from_world});
    changes.associations.push_back({id, keyframe.points});
    changes.last_keyframe = std::max(changes.last_keyframe, id);
  }
  for (const auto& [id, point] : map->points()) {
    MapPoint copy = point;
    copy.observations.clear();
    changes.points.push_back(std::move(copy));
  }
  changes.removed_points = map->TakeRemovedPoints();
  changes.removed_keyframes = map->TakeRemovedKeyframes();
  return update;
}

std::vector<KeyframeId> ApplySubmapUpdate(const SubmapUpdate& update, SubmapReplica* replica) {
  Map& map = replica->map;
  if (update.submap != map.id()) return {};
  const bool stale = update.revision < replica->full_state_revision;
  if (update.camera && !replica->camera) replica->camera = update.camera;
  // Points and associations first: a new keyframe then finds the points it observes.
  if (!stale) ApplyLocalMapUpdate(update.changes, &map);
  const bool has_manifest = !update.manifest.empty() && update.revision >= replica->manifest_revision;
  if (has_manifest) {
    replica->manifest = update.manifest;
    replica->manifest_revision = update.revision;
  }
  const std::unordered_set<KeyframeId> listed(replica->manifest.begin(), replica->manifest.end());
  for (const Keyframe& keyframe : update.new_keyframes) {
    if (map.FindKeyframe(keyframe.id) || SubmapOf(keyframe.id) != map.id()) continue;
    // A keyframe the newest manifest no longer lists was culled since.
    if (replica->manifest_revision > update.revision && !listed.count(keyframe.id)) continue;
    map.AddKeyframe(Transportable(keyframe));
    map.UpdateConnections(keyframe.id);
  }
  if (has_manifest) {
    std::vector<KeyframeId> unlisted;
    for (const auto& [id, keyframe] : map.keyframes()) {
      if (!listed.count(id)) unlisted.push_back(id);
    }
    for (KeyframeId id : unlisted) map.RemoveKeyframe(id);
  }
  if (!stale) {
    // A closed submap is reopened when the tracker relocalizes in it: the newest update says.
    if (update.revision >= replica->newest_revision) replica->closed = update.closed;
    replica->newest_revision = std::max(replica->newest_revision, update.revision);
    if (update.full_state) replica->full_state_revision = std::max(replica->full_state_revision, update.revision);
  }
  std::vector<KeyframeId> missing;
  for (KeyframeId id : replica->manifest) {
    if (!map.FindKeyframe(id)) missing.push_back(id);
  }
  return missing;
}

std::vector<SubmapUpdate> SplitSubmapUpdate(const SubmapUpdate& update, size_t max_bytes) {
  const auto empty_part = [&]() {
    SubmapUpdate part;
    part.submap = update.submap;
    part.revision = update.revision;
    part.closed = update.closed;
    part.full_state = update.full_state;
    part.camera = update.camera;
    return part;
  };
  std::vector<SubmapUpdate> parts;
  for (LocalMapUpdate& changes : SplitLocalMapUpdate(update.changes, max_bytes)) {
    SubmapUpdate part = empty_part();
    part.changes = std::move(changes);
    parts.push_back(std::move(part));
  }
  parts.front().manifest = update.manifest;
  // Keyframes after the points they observe (a lost points part is repaired by the next update).
  SubmapUpdate part = empty_part();
  size_t bytes = 0;
  for (const Keyframe& keyframe : update.new_keyframes) {
    const size_t size = KeyframeMessageBytes(keyframe);
    if (!part.new_keyframes.empty() && bytes + size > max_bytes) {
      parts.push_back(std::move(part));
      part = empty_part();
      bytes = 0;
    }
    part.new_keyframes.push_back(keyframe);
    bytes += size;
  }
  if (!part.new_keyframes.empty()) parts.push_back(std::move(part));
  return parts;
}

}  // namespace stitch
