#include "stitch/map/map.h"

#include <algorithm>

#include "stitch/util/error.h"

namespace stitch {
namespace {

constexpr int kCovisibilityThreshold = 15;

}  // namespace

int Keyframe::CountPoints() const {
  int count = 0;
  for (const auto& p : points) count += p.valid();
  return count;
}

Keyframe KeyframeFromFrame(const Frame& frame, KeyframeId id) {
  Keyframe keyframe;
  keyframe.id = id;
  keyframe.frame_index = frame.frame_index;
  keyframe.t_ns = frame.t_ns;
  keyframe.cam_from_world = frame.cam_from_world.value_or(Rigid3d());
  keyframe.keypoints = frame.keypoints;
  keyframe.undistorted = frame.undistorted;
  keyframe.descriptors = frame.descriptors.clone();
  keyframe.bow = frame.bow;
  keyframe.bow_features = frame.bow_features;
  keyframe.grid = frame.grid;
  keyframe.points = frame.points;
  for (size_t i = 0; i < frame.outlier.size(); ++i) {
    if (frame.outlier[i]) keyframe.points[i] = MapPointId();
  }
  return keyframe;
}

Frame FrameFromKeyframe(const Keyframe& keyframe) {
  Frame frame;
  frame.frame_index = keyframe.frame_index;
  frame.t_ns = keyframe.t_ns;
  frame.keypoints = keyframe.keypoints;
  frame.undistorted = keyframe.undistorted;
  frame.descriptors = keyframe.descriptors;
  frame.bow = keyframe.bow;
  frame.bow_features = keyframe.bow_features;
  frame.grid = keyframe.grid;
  frame.points = keyframe.points;
  frame.outlier.assign(keyframe.points.size(), 0);
  frame.cam_from_world = keyframe.cam_from_world;
  return frame;
}

Keyframe UnlinkedCopy(const Keyframe& keyframe) {
  Keyframe copy = keyframe;
  copy.covisibility.clear();
  copy.ordered.clear();
  copy.parent = KeyframeId();
  copy.children.clear();
  return copy;
}

Map::Map(SubmapId id, ScalePyramid pyramid, uint32_t first_point_index)
    : id_(id), pyramid_(std::move(pyramid)), next_point_index_(first_point_index) {}

Keyframe& Map::AddKeyframe(Keyframe keyframe) {
  const KeyframeId id = keyframe.id;
  if (keyframes_.count(id)) throw Error("Map::AddKeyframe: keyframe " + std::to_string(id.value) + " exists");
  Keyframe& inserted = keyframes_.emplace(id, std::move(keyframe)).first->second;
  for (size_t i = 0; i < inserted.points.size(); ++i) {
    const MapPointId p = inserted.points[i];
    if (!p.valid()) continue;
    MapPoint* point = FindPoint(p);
    if (!point) {
      inserted.points[i] = MapPointId();
      continue;
    }
    point->observations[id] = static_cast<int>(i);
  }
  return inserted;
}

Keyframe* Map::FindKeyframe(KeyframeId id) {
  const auto it = keyframes_.find(id);
  return it == keyframes_.end() ? nullptr : &it->second;
}

const Keyframe* Map::FindKeyframe(KeyframeId id) const {
  const auto it = keyframes_.find(id);
  return it == keyframes_.end() ? nullptr : &it->second;
}

void Map::RemoveKeyframe(KeyframeId id) {
  Keyframe* keyframe = FindKeyframe(id);
  if (!keyframe) return;
  const std::vector<MapPointId> observed = keyframe->points;
  for (MapPointId p : observed) {
    if (p.valid()) EraseObservation(id, p);
  }
  // Spanning tree: children go to this keyframe's parent (or, at the root, the first child).
  KeyframeId new_parent = keyframe->parent;
  const std::set<KeyframeId> children = keyframe->children;
  if (!new_parent.valid() && !children.empty()) new_parent = *children.begin();
  for (KeyframeId child : children) {
    if (child == new_parent) continue;
    if (Keyframe* c = FindKeyframe(child)) {
      c->parent = new_parent;
      if (Keyframe* np = FindKeyframe(new_parent)) np->children.insert(child);
    }
  }
  if (Keyframe* np = FindKeyframe(new_parent)) {
    np->children.erase(id);
    if (np->parent == id) np->parent = KeyframeId();
  }
  if (Keyframe* parent = FindKeyframe(keyframe->parent)) parent->children.erase(id);
  const std::map<KeyframeId, int> neighbours = keyframe->covisibility;
  keyframes_.erase(id);
  if (journal_removals_) removed_keyframes_.push_back(id);
  for (const auto& [neighbour, weight] : neighbours) {
    if (Keyframe* n = FindKeyframe(neighbour)) {
      n->covisibility.erase(id);
      SetOrderedCovisibility(n);
    }
  }
}

MapPointId Map::NewPointId() {
  return MakeMapPointId(id_, next_point_index_++);
}

MapPoint& Map::AddPoint(MapPoint point) {
  const MapPointId id = point.id;
  if (!id.valid()) throw Error("Map::AddPoint: invalid id");
  return points_.insert_or_assign(id, std::move(point)).first->second;
}

MapPoint* Map::FindPoint(MapPointId id) {
  const auto it = points_.find(id);
  return it == points_.end() ? nullptr : &it->second;
}

const MapPoint* Map::FindPoint(MapPointId id) const {
  const auto it = points_.find(id);
  return it == points_.end() ? nullptr : &it->second;
}

void Map::RemovePoint(MapPointId id) {
  MapPoint* point = FindPoint(id);
  if (!point) return;
  for (const auto& [kf, feature] : point->observations) {
    if (Keyframe* keyframe = FindKeyframe(kf)) {
      if (feature >= 0 && feature < static_cast<int>(keyframe->points.size()) && keyframe->points[feature] == id) {
        keyframe->points[feature] = MapPointId();
      }
    }
  }
  points_.erase(id);
  if (journal_removals_) removed_points_.push_back(id);
}

void Map::AddObservation(KeyframeId kf, int feature, MapPointId point_id) {
  Keyframe* keyframe = FindKeyframe(kf);
  MapPoint* point = FindPoint(point_id);
  if (!keyframe || !point || feature < 0 || feature >= static_cast<int>(keyframe->points.size())) return;
  const MapPointId previous = keyframe->points[feature];
  if (previous.valid() && previous != point_id) {
    if (MapPoint* old = FindPoint(previous)) old->observations.erase(kf);
  }
  // A keyframe observes a point through one feature only.
  const auto existing = point->observations.find(kf);
  if (existing != point->observations.end() && existing->second != feature &&
      existing->second < static_cast<int>(keyframe->points.size())) {
    keyframe->points[existing->second] = MapPointId();
  }
  keyframe->points[feature] = point_id;
  point->observations[kf] = feature;
}

void Map::EraseObservation(KeyframeId kf, MapPointId point_id, int min_observations) {
  MapPoint* point = FindPoint(point_id);
  if (!point) return;
  const auto it = point->observations.find(kf);
  if (it == point->observations.end()) return;
  if (Keyframe* keyframe = FindKeyframe(kf)) {
    if (it->second < static_cast<int>(keyframe->points.size()) && keyframe->points[it->second] == point_id) {
      keyframe->points[it->second] = MapPointId();
    }
  }
  point->observations.erase(it);
  if (static_cast<int>(point->observations.size()) < min_observations) {
    RemovePoint(point_id);
    return;
  }
  if (point->reference_keyframe == kf) point->reference_keyframe = point->observations.begin()->first;
}

void Map::ReplacePoint(MapPointId duplicate, MapPointId keep) {
  if (duplicate == keep) return;
  MapPoint* dup = FindPoint(duplicate);
  MapPoint* kept = FindPoint(keep);
  if (!dup || !kept) return;
  const std::map<KeyframeId, int> observations = dup->observations;
  kept->visible += dup->visible;
  kept->found += dup->found;
  for (const auto& [kf, feature] : observations) {
    Keyframe* keyframe = FindKeyframe(kf);
    if (!keyframe) continue;
    if (kept->observations.count(kf)) {
      // The keyframe sees both through different features: keep its existing `keep` feature.
      if (feature < static_cast<int>(keyframe->points.size()) && keyframe->points[feature] == duplicate) {
        keyframe->points[feature] = MapPointId();
      }
    } else {
      keyframe->points[feature] = keep;
      kept->observations[kf] = feature;
    }
  }
  dup->observations.clear();
  points_.erase(duplicate);
  if (journal_removals_) removed_points_.push_back(duplicate);
  UpdatePointAppearance(keep);
  UpdatePointGeometry(keep);
}

void Map::UpdatePointAppearance(MapPointId id) {
  MapPoint* point = FindPoint(id);
  if (!point || point->observations.empty()) return;
  std::vector<const uint8_t*> descriptors;
  for (const auto& [kf, feature] : point->observations) {
    const Keyframe* keyframe = FindKeyframe(kf);
    if (keyframe && feature < keyframe->descriptors.rows)
      descriptors.push_back(keyframe->descriptors.ptr<uint8_t>(feature));
  }
  if (descriptors.empty()) return;
  // The descriptor closest (in median distance) to all others.
  const size_t n = descriptors.size();
  int best_median = 1 << 30;
  size_t best = 0;
  std::vector<int> distances(n);
  for (size_t i = 0; i < n; ++i) {
    for (size_t j = 0; j < n; ++j) distances[j] = i == j ? 0 : HammingDistance(descriptors[i], descriptors[j]);
    std::nth_element(distances.begin(), distances.begin() + (n - 1) / 2, distances.end());
    const int median = distances[(n - 1) / 2];
    if (median < best_median) {
      best_median = median;
      best = i;
    }
  }
  point->descriptor = ToDescriptor(descriptors[best]);
}

void Map::UpdatePointGeometry(MapPointId id) {
  MapPoint* point = FindPoint(id);
  if (!point || point->observations.empty()) return;
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();
  int count = 0;
  for (const auto& [kf, feature] : point->observations) {
    const Keyframe* keyframe = FindKeyframe(kf);
    if (!keyframe) continue;
    normal += (point->position - keyframe->Centre()).normalized();
    ++count;
  }
  if (count == 0) return;
  point->normal = normal.normalized();
  if (!point->reference_keyframe.valid() || !FindKeyframe(point->reference_keyframe) ||
      !point->observations.count(point->reference_keyframe)) {
    point->reference_keyframe = point->observations.begin()->first;
  }
  const Keyframe* reference = FindKeyframe(point->reference_keyframe);
  const int feature = point->observations.at(point->reference_keyframe);
  const int level = reference->keypoints[feature].octave;
  const double distance = (point->position - reference->Centre()).norm();
  point->max_distance = static_cast<float>(distance * pyramid_.scale[level]);
  point->min_distance = point->max_distance / pyramid_.scale.back();
}

void Map::SetOrderedCovisibility(Keyframe* keyframe) {
  keyframe->ordered.clear();
  std::pair<int, KeyframeId> best{0, KeyframeId()};
  for (const auto& [other, weight] : keyframe->covisibility) {
    if (weight >= kCovisibilityThreshold) keyframe->ordered.push_back({weight, other});
    if (weight > best.first) best = {weight, other};
  }
  if (keyframe->ordered.empty() && best.second.valid()) keyframe->ordered.push_back(best);
  std::sort(keyframe->ordered.begin(), keyframe->ordered.end(), [](const auto& a, const auto& b) {
    return a.first > b.first || (a.first == b.first && a.second < b.second);
  });
}

void Map::UpdateConnections(KeyframeId id) {
  Keyframe* keyframe = FindKeyframe(id);
  if (!keyframe) return;
  std::map<KeyframeId, int> counts;
  for (MapPointId p : keyframe->points) {
    const MapPoint* point = p.valid() ? FindPoint(p) : nullptr;
    if (!point) continue;
    for (const auto& [other, feature] : point->observations) {
      if (other != id) ++counts[other];
    }
  }
  // Drop stale links, then set both directions.
  for (const auto& [other, weight] : keyframe->covisibility) {
    if (!counts.count(other)) {
      if (Keyframe* o = FindKeyframe(other)) {
        o->covisibility.erase(id);
        SetOrderedCovisibility(o);
      }
    }
  }
  keyframe->covisibility = counts;
  for (const auto& [other, weight] : counts) {
    if (Keyframe* o = FindKeyframe(other)) {
      // Its order is sorted again only where the link changed (most stay as they were).
      const auto [link, added] = o->covisibility.try_emplace(id, weight);
      if (!added && link->second == weight) continue;
      link->second = weight;
      SetOrderedCovisibility(o);
    }
  }
  SetOrderedCovisibility(keyframe);
  // First connection: the strongest neighbour becomes the parent in the spanning tree.
  if (!keyframe->parent.valid() && !keyframe->ordered.empty()) {
    const KeyframeId parent = keyframe->ordered.front().second;
    if (Keyframe* p = FindKeyframe(parent); p && p->parent != id) {
      keyframe->parent = parent;
      p->children.insert(id);
    }
  }
}

void Map::ConnectAll() {
  std::vector<KeyframeId> ids;
  for (auto& [id, keyframe] : keyframes_) {
    ids.push_back(id);
    keyframe.covisibility.clear();
    keyframe.parent = KeyframeId();
    keyframe.children.clear();
    for (MapPointId p : keyframe.points) {
      const MapPoint* point = p.valid() ? FindPoint(p) : nullptr;
      if (!point) continue;
      for (const auto& [other, feature] : point->observations) {
        if (other != id) ++keyframe.covisibility[other];
      }
    }
  }
  for (auto& [id, keyframe] : keyframes_) SetOrderedCovisibility(&keyframe);
  std::sort(ids.begin(), ids.end());
  for (KeyframeId id : ids) {
    Keyframe& keyframe = keyframes_.at(id);
    if (keyframe.ordered.empty()) continue;
    const KeyframeId parent = keyframe.ordered.front().second;
    if (Keyframe* p = FindKeyframe(parent); p && p->parent != id) {
      keyframe.parent = parent;
      p->children.insert(id);
    }
  }
}

std::vector<KeyframeId> Map::BestCovisible(KeyframeId id, int n) const {
  std::vector<KeyframeId> result;
  const Keyframe* keyframe = FindKeyframe(id);
  if (!keyframe) return result;
  for (const auto& [weight, other] : keyframe->ordered) {
    if (static_cast<int>(result.size()) >= n) break;
    result.push_back(other);
  }
  return result;
}

std::vector<KeyframeId> Map::CovisibleAtLeast(KeyframeId id, int min_weight) const {
  std::vector<KeyframeId> result;
  const Keyframe* keyframe = FindKeyframe(id);
  if (!keyframe) return result;
  for (const auto& [weight, other] : keyframe->ordered) {
    if (weight < min_weight) break;
    result.push_back(other);
  }
  return result;
}

std::vector<MapPointId> Map::TakeRemovedPoints() {
  std::vector<MapPointId> taken;
  taken.swap(removed_points_);
  return taken;
}

std::vector<KeyframeId> Map::TakeRemovedKeyframes() {
  std::vector<KeyframeId> taken;
  taken.swap(removed_keyframes_);
  return taken;
}

double Map::MedianDepth(KeyframeId id) const {
  const Keyframe* keyframe = FindKeyframe(id);
  if (!keyframe) return 0;
  std::vector<double> depths;
  for (MapPointId p : keyframe->points) {
    const MapPoint* point = p.valid() ? FindPoint(p) : nullptr;
    if (point) depths.push_back((keyframe->cam_from_world * point->position).z());
  }
  if (depths.empty()) return 0;
  std::nth_element(depths.begin(), depths.begin() + depths.size() / 2, depths.end());
  return depths[depths.size() / 2];
}

}  // namespace stitch
