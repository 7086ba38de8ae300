#pragma once
// Submaps built in a test: one grown keyframe by keyframe, and one built whole sent as its mapper
// would, one update per keyframe.

#include <algorithm>
#include <vector>

#include "stitch/map/submap_update.h"

namespace stitch::testing {

// Adds keyframe `index` of a submap grown keyframe by keyframe (a strip, 0.5 m a keyframe along
// x): 40 features, the first 30 observing points 10 * index to 10 * index + 29, 20 of them the
// previous keyframe's; those it shares are moved `refine_m` in z (as its adjustment would move
// them). Brings its covisibility up to date.
inline KeyframeId AddChainedKeyframe(Map* map, uint32_t index, double refine_m = 0) {
  Keyframe keyframe;
  keyframe.id = MakeKeyframeId(map->id(), index);
  keyframe.frame_index = static_cast<int>(10 * index);
  keyframe.cam_from_world = Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(-0.5 * index, 0, 0));
  const int n = 40;
  keyframe.descriptors = cv::Mat(n, 32, CV_8U, cv::Scalar(index));
  for (int i = 0; i < n; ++i) {
    cv::KeyPoint kp(10.0f + 5 * i, 20.0f + index, 31);
    kp.octave = i % 3;
    keyframe.keypoints.push_back(kp);
  }
  keyframe.points.assign(n, MapPointId());
  for (int i = 0; i < 30; ++i) {
    const uint32_t point_index = 10 * index + static_cast<uint32_t>(i);
    const MapPointId id = MakeMapPointId(map->id(), point_index);
    if (MapPoint* known = map->FindPoint(id)) {
      known->position.z() += refine_m;
    } else {
      MapPoint point;
      point.id = id;
      point.position = Eigen::Vector3d(0.1 * point_index, 0.2, 5.0);
      map->AddPoint(point);
    }
    keyframe.points[i] = id;
  }
  const KeyframeId id = keyframe.id;
  map->AddKeyframe(std::move(keyframe));
  map->UpdateConnections(id);
  return id;
}

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
