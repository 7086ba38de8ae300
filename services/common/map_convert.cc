#include "services/common/map_convert.h"

#include <cmath>
#include <cstring>

#include "services/common/convert.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

// Bounds of what a map can hold, in its units (the first camera's median scene depth): a point or
// a camera a million of them away, or a point index past 2^28 (the tracker numbers its points from
// 0, the mapper from 2^24, one at a time), is no map's: a forged or damaged update. Finite values
// beyond them passed every check (a point at 1e30, an index of 2^30) and went into the merged map.
constexpr double kMaxMapCoordinate = 1e6;
constexpr int32_t kMaxPointIndex = 1 << 28;

bool Finite(const float* values, int n) {
  for (int i = 0; i < n; ++i) {
    if (!std::isfinite(values[i])) return false;
  }
  return true;
}

bool WithinMap(const float* values, int n) {
  for (int i = 0; i < n; ++i) {
    if (std::abs(values[i]) > kMaxMapCoordinate) return false;
  }
  return true;
}

int32_t CheckedPointIndex(int32_t index, const std::string& what) {
  if (index >= kMaxPointIndex) {
    throw Error(what + ": point index " + std::to_string(index) + " is past any map's (" +
                std::to_string(kMaxPointIndex) + ")");
  }
  return index;
}

// A keyframe's pose, refused where its camera is outside any map.
Rigid3d PlausiblePose(const stitch::rigid3_t& message, const std::string& what) {
  const Rigid3d pose = FromMessage(message);
  if (!(pose.CentreInWorld().cwiseAbs().maxCoeff() <= kMaxMapCoordinate))
    throw Error(what + ": a keyframe's camera lies outside any map");
  return pose;
}

int32_t PointIndexOrNone(MapPointId id) {
  return id.valid() ? static_cast<int32_t>(IndexOf(id)) : -1;
}

MapPointId PointIdOrNone(SubmapId submap, int32_t index) {
  return index >= 0 ? MakeMapPointId(submap, static_cast<uint32_t>(CheckedPointIndex(index, "association")))
                    : MapPointId();
}

}  // namespace

stitch::map_point_t ToMessage(const MapPoint& point) {
  stitch::map_point_t m{};
  m.point_index = static_cast<int32_t>(IndexOf(point.id));
  for (int i = 0; i < 3; ++i) {
    m.position[i] = static_cast<float>(point.position[i]);
    m.viewing_direction[i] = static_cast<float>(point.normal[i]);
  }
  m.min_distance = point.min_distance;
  m.max_distance = point.max_distance;
  std::memcpy(m.descriptor, point.descriptor.data(), 32);
  m.num_observations = static_cast<int16_t>(std::min<size_t>(point.observations.size(), 32767));
  return m;
}

MapPoint FromMessage(const stitch::map_point_t& m, SubmapId submap) {
  if (m.point_index < 0) throw Error("map point with a negative index");
  if (!Finite(m.position, 3) || !Finite(m.viewing_direction, 3) || !std::isfinite(m.min_distance) ||
      !std::isfinite(m.max_distance)) {
    throw Error("map point " + std::to_string(m.point_index) + " has non-finite values");
  }
  CheckedPointIndex(m.point_index, "map point");
  if (!WithinMap(m.position, 3) || !(m.min_distance >= 0) || !(m.max_distance <= kMaxMapCoordinate)) {
    throw Error("map point " + std::to_string(m.point_index) + " lies outside any map");
  }
  MapPoint point;
  point.id = MakeMapPointId(submap, static_cast<uint32_t>(m.point_index));
  point.position = Eigen::Vector3d(m.position[0], m.position[1], m.position[2]);
  point.normal = Eigen::Vector3d(m.viewing_direction[0], m.viewing_direction[1], m.viewing_direction[2]);
  point.min_distance = m.min_distance;
  point.max_distance = m.max_distance;
  std::memcpy(point.descriptor.data(), m.descriptor, 32);
  return point;
}

stitch::keyframe_t ToMessage(const Keyframe& keyframe, const Camera& camera, const std::vector<MapPoint>& new_points) {
  stitch::keyframe_t m{};
  m.keyframe_id = keyframe.id.value;
  m.submap_id = SubmapOf(keyframe.id).value;
  m.frame_index = keyframe.frame_index;
  m.t_ns = keyframe.t_ns;
  m.cam_from_submap = ToMessage(keyframe.cam_from_world);
  m.camera = ToMessage(camera);
  const int n = static_cast<int>(keyframe.keypoints.size());
  m.num_features = n;
  m.x_eighth_px.resize(n);
  m.y_eighth_px.resize(n);
  m.octave.resize(n);
  m.angle.resize(n);
  m.point_index.resize(n);
  for (int i = 0; i < n; ++i) {
    const cv::KeyPoint& k = keyframe.keypoints[i];
    m.x_eighth_px[i] = static_cast<int16_t>(std::lround(k.pt.x * 8));
    m.y_eighth_px[i] = static_cast<int16_t>(std::lround(k.pt.y * 8));
    m.octave[i] = static_cast<int8_t>(k.octave);
    m.angle[i] = static_cast<int8_t>(static_cast<int>(std::lround(k.angle * 256.0f / 360.0f)) & 255);
    m.point_index[i] = PointIndexOrNone(keyframe.points[i]);
  }
  m.num_descriptor_bytes = 32 * n;
  m.descriptors.assign(keyframe.descriptors.data, keyframe.descriptors.data + 32 * n);
  m.num_new_points = static_cast<int32_t>(new_points.size());
  for (const MapPoint& p : new_points) m.new_points.push_back(ToMessage(p));
  return m;
}

ReceivedKeyframe FromMessage(const stitch::keyframe_t& m, const ScalePyramid& pyramid) {
  const std::string what = "keyframe " + std::to_string(m.keyframe_id);
  const KeyframeId id(m.keyframe_id);
  if (!id.valid() || SubmapOf(id).value != m.submap_id)
    throw Error(what + ": id does not belong to submap " + std::to_string(m.submap_id));
  const int n = m.num_features;
  if (n < 0 || static_cast<int>(m.x_eighth_px.size()) != n || static_cast<int>(m.point_index.size()) != n ||
      m.num_descriptor_bytes != 32 * n) {
    throw Error(what + ": " + std::to_string(m.num_descriptor_bytes / 32) + " descriptors for " + std::to_string(n) +
                " features");
  }
  ReceivedKeyframe received;
  received.camera = FromMessage(m.camera);
  Keyframe& k = received.keyframe;
  k.id = id;
  k.frame_index = m.frame_index;
  k.t_ns = m.t_ns;
  k.cam_from_world = PlausiblePose(m.cam_from_submap, what);
  k.keypoints.resize(n);
  k.points.resize(n);
  const SubmapId submap(m.submap_id);
  for (int i = 0; i < n; ++i) {
    const int octave = m.octave[i];
    if (octave < 0 || octave >= pyramid.num_levels)
      throw Error(what + ": feature " + std::to_string(i) + " at pyramid level " + std::to_string(octave));
    const float x = m.x_eighth_px[i] / 8.0f, y = m.y_eighth_px[i] / 8.0f;
    if (x < 0 || y < 0 || x >= received.camera.width() || y >= received.camera.height()) {
      throw Error(what + ": feature " + std::to_string(i) + " lies outside the image");
    }
    cv::KeyPoint kp(x, y, 31.0f * pyramid.scale[octave], (static_cast<uint8_t>(m.angle[i])) * 360.0f / 256.0f);
    kp.octave = octave;
    k.keypoints[i] = kp;
    k.points[i] = PointIdOrNone(submap, m.point_index[i]);
  }
  k.descriptors = cv::Mat(n, 32, CV_8U);
  if (n > 0) std::memcpy(k.descriptors.data, m.descriptors.data(), 32 * n);
  if (m.num_new_points != static_cast<int>(m.new_points.size())) throw Error(what + ": inconsistent point count");
  for (const auto& p : m.new_points) received.new_points.push_back(FromMessage(p, submap));
  return received;
}

namespace {

// Local-map and submap updates share their change arrays by name, except the poses' ids and
// count, which are given as members.
template <class Message>
void EncodeChanges(const LocalMapUpdate& changes, std::vector<int64_t> Message::*pose_ids, int32_t Message::*num_poses,
                   Message* m) {
  for (const auto& [id, pose] : changes.keyframe_poses) {
    (m->*pose_ids).push_back(id.value);
    m->cam_from_submap.push_back(ToMessage(pose));
  }
  m->*num_poses = static_cast<int32_t>((m->*pose_ids).size());
  for (const auto& [id, points] : changes.associations) {
    stitch::keyframe_association_t a{};
    a.keyframe_id = id.value;
    a.num_features = static_cast<int32_t>(points.size());
    for (MapPointId p : points) a.point_index.push_back(PointIndexOrNone(p));
    m->associations.push_back(std::move(a));
  }
  m->num_associations = static_cast<int32_t>(m->associations.size());
  for (const MapPoint& point : changes.points) m->points.push_back(ToMessage(point));
  m->num_points = static_cast<int32_t>(m->points.size());
  for (MapPointId id : changes.removed_points) m->removed_point_index.push_back(static_cast<int32_t>(IndexOf(id)));
  m->num_removed_points = static_cast<int32_t>(m->removed_point_index.size());
  for (KeyframeId id : changes.removed_keyframes) m->removed_keyframe_ids.push_back(id.value);
  m->num_removed_keyframes = static_cast<int32_t>(m->removed_keyframe_ids.size());
}

// Fills `changes` (whose submap is set); throws stitch::Error naming `what` for inconsistent arrays.
template <class Message>
void DecodeChanges(const Message& m, const std::vector<int64_t>& pose_ids, const std::string& what,
                   LocalMapUpdate* changes) {
  const SubmapId submap = changes->submap;
  if (pose_ids.size() != m.cam_from_submap.size()) throw Error(what + ": poses and ids disagree");
  const auto own = [&](int64_t id) {
    if (SubmapOf(KeyframeId(id)) != submap)
      throw Error(what + ": keyframe " + std::to_string(id) + " of another submap");
    return KeyframeId(id);
  };
  for (size_t i = 0; i < pose_ids.size(); ++i) {
    changes->keyframe_poses.push_back({own(pose_ids[i]), PlausiblePose(m.cam_from_submap[i], what)});
  }
  for (const auto& a : m.associations) {
    if (a.num_features != static_cast<int>(a.point_index.size())) throw Error(what + ": inconsistent association");
    std::vector<MapPointId> points;
    for (int32_t index : a.point_index) points.push_back(PointIdOrNone(submap, index));
    changes->associations.push_back({own(a.keyframe_id), std::move(points)});
  }
  for (const auto& p : m.points) changes->points.push_back(FromMessage(p, submap));
  for (int32_t index : m.removed_point_index) {
    if (index >= 0) changes->removed_points.push_back(MakeMapPointId(submap, static_cast<uint32_t>(index)));
  }
  for (int64_t id : m.removed_keyframe_ids) changes->removed_keyframes.push_back(own(id));
}

SubmapId CheckedSubmapId(int64_t value, const std::string& what) {
  const SubmapId submap(value);
  if (!submap.valid() || IndexOf(submap) != 0) throw Error(what + ": invalid submap id " + std::to_string(value));
  return submap;
}

}  // namespace

std::vector<stitch::local_map_update_t> ToMessages(const LocalMapUpdate& update, size_t max_part_bytes) {
  const std::vector<LocalMapUpdate> parts = SplitLocalMapUpdate(update, max_part_bytes);
  std::vector<stitch::local_map_update_t> messages;
  for (size_t p = 0; p < parts.size(); ++p) {
    const LocalMapUpdate& part = parts[p];
    stitch::local_map_update_t m{};
    m.submap_id = part.submap.value;
    m.revision = part.revision;
    m.part = static_cast<int32_t>(p);
    m.num_parts = static_cast<int32_t>(parts.size());
    m.last_keyframe_id = part.last_keyframe.value;
    m.queued_keyframes = part.queued_keyframes;
    EncodeChanges(part, &stitch::local_map_update_t::keyframe_ids, &stitch::local_map_update_t::num_keyframes, &m);
    messages.push_back(std::move(m));
  }
  return messages;
}

LocalMapUpdate FromMessage(const stitch::local_map_update_t& m) {
  LocalMapUpdate update;
  update.submap = CheckedSubmapId(m.submap_id, "local map update");
  update.revision = m.revision;
  update.last_keyframe = KeyframeId(m.last_keyframe_id);
  update.queued_keyframes = m.queued_keyframes;
  DecodeChanges(m, m.keyframe_ids, "local map update", &update);
  return update;
}

stitch::submap_update_t ToMessage(const SubmapUpdate& part, int32_t index, int32_t count) {
  stitch::submap_update_t m{};
  m.submap_id = part.submap.value;
  m.revision = part.revision;
  m.part = index;
  m.num_parts = count;
  m.closed = part.closed;
  m.full_state = part.full_state;
  for (const Keyframe& keyframe : part.new_keyframes) m.keyframes.push_back(ToMessage(keyframe, *part.camera, {}));
  m.num_keyframes = static_cast<int32_t>(m.keyframes.size());
  EncodeChanges(part.changes, &stitch::submap_update_t::pose_keyframe_ids, &stitch::submap_update_t::num_poses, &m);
  for (KeyframeId id : part.manifest) m.manifest_keyframe_ids.push_back(id.value);
  m.num_manifest = static_cast<int32_t>(m.manifest_keyframe_ids.size());
  return m;
}

std::vector<stitch::submap_update_t> ToMessages(const SubmapUpdate& update, size_t max_part_bytes) {
  const std::vector<SubmapUpdate> parts = SplitSubmapUpdate(update, max_part_bytes);
  std::vector<stitch::submap_update_t> messages;
  for (size_t p = 0; p < parts.size(); ++p) {
    messages.push_back(ToMessage(parts[p], static_cast<int32_t>(p), static_cast<int32_t>(parts.size())));
  }
  return messages;
}

SubmapUpdate FromMessage(const stitch::submap_update_t& m, const ScalePyramid& pyramid) {
  const std::string what = "submap update " + std::to_string(m.submap_id);
  SubmapUpdate update;
  update.submap = CheckedSubmapId(m.submap_id, "submap update");
  update.revision = m.revision;
  update.closed = m.closed;
  update.full_state = m.full_state;
  for (const auto& k : m.keyframes) {
    if (k.submap_id != m.submap_id)
      throw Error(what + ": keyframe " + std::to_string(k.keyframe_id) + " of another submap");
    ReceivedKeyframe received = FromMessage(k, pyramid);
    update.camera = received.camera;
    update.new_keyframes.push_back(std::move(received.keyframe));
  }
  update.changes.submap = update.submap;
  update.changes.revision = m.revision;
  DecodeChanges(m, m.pose_keyframe_ids, what, &update.changes);
  for (int64_t id : m.manifest_keyframe_ids) {
    if (SubmapOf(KeyframeId(id)) != update.submap) throw Error(what + ": manifest lists a keyframe of another submap");
    update.manifest.push_back(KeyframeId(id));
  }
  return update;
}

std::vector<stitch::submap_update_t> ToMessages(const std::vector<SubmapUpdate>& updates) {
  std::vector<stitch::submap_update_t> messages;
  for (const SubmapUpdate& update : updates) {
    for (auto& part : ToMessages(update)) messages.push_back(std::move(part));
  }
  return messages;
}

}  // namespace stitch
