#pragma once
// A submap built whole in a test, sent as its mapper would: one update per keyframe.

#include <algorithm>
#include <vector>

#include "stitch/map/submap_update.h"

namespace stitch::testing {

// One update per keyframe of `map`, in id order: the keyframe in full with its pose, its
// associations and its points, the revision counting up from 1, and the manifest of the
// keyframes sent so far. Brings each keyframe's covisibility up to date as it goes.
inline std::vector<SubmapUpdate> KeyframeByKeyframeUpdates(Map* map, const Camera& camera) {
  std::vector<KeyframeId> ids;
  for (const auto& [id, keyframe] : map->keyframes()) ids.push_back(id);
  std::sort(ids.begin(), ids.end());
  std::vector<SubmapUpdate> updates;
  for (size_t k = 0; k < ids.size(); ++k) {
    const KeyframeId id = ids[k];
    map->UpdateConnections(id);
    const Keyframe& keyframe = *map->FindKeyframe(id);
    LocalMapUpdate changes;
    changes.revision = static_cast<int>(k) + 1;
    changes.last_keyframe = id;
    changes.keyframe_poses.push_back({id, keyframe.cam_from_world});
    changes.associations.push_back({id, keyframe.points});
    for (MapPointId p : keyframe.points) {
      MapPoint copy = *map->FindPoint(p);
      copy.observations.clear();
      changes.points.push_back(copy);
    }
    updates.push_back(MakeKeyframeSubmapUpdate(*map, id, camera, changes));
    updates.back().manifest.assign(ids.begin(), ids.begin() + static_cast<std::ptrdiff_t>(k) + 1);
  }
  return updates;
}

}  // namespace stitch::testing
