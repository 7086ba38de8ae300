#include "stitch/map/matcher.h"

#include <algorithm>
#include <array>
#include <cmath>

#include "stitch/features/descriptor.h"

namespace stitch {
namespace {

constexpr int kHistogramBins = 30;

// Rotation consistency: keeps the matches whose orientation change falls in the three largest
// bins (a bin under 10% of the largest does not count).
class RotationHistogram {
 public:
  void Add(float angle_a, float angle_b, int index) {
    float delta = angle_a - angle_b;
    if (delta < 0) delta += 360.0f;
    int bin = static_cast<int>(std::round(delta * kHistogramBins / 360.0f));
    if (bin == kHistogramBins) bin = 0;
    bins_[bin].push_back(index);
  }
  // Indices outside the kept bins.
  std::vector<int> Rejected() const {
    std::array<size_t, 3> top{0, 0, 0};
    std::array<int, 3> which{-1, -1, -1};
    for (int b = 0; b < kHistogramBins; ++b) {
      const size_t n = bins_[b].size();
      if (n > top[0]) {
        top = {n, top[0], top[1]};
        which = {b, which[0], which[1]};
      } else if (n > top[1]) {
        top = {top[0], n, top[1]};
        which = {which[0], b, which[1]};
      } else if (n > top[2]) {
        top[2] = n;
        which[2] = b;
      }
    }
    if (top[1] < 0.1 * top[0])
      which[1] = which[2] = -1;
    else if (top[2] < 0.1 * top[0])
      which[2] = -1;
    std::vector<int> rejected;
    for (int b = 0; b < kHistogramBins; ++b) {
      if (b == which[0] || b == which[1] || b == which[2]) continue;
      rejected.insert(rejected.end(), bins_[b].begin(), bins_[b].end());
    }
    return rejected;
  }

 private:
  std::array<std::vector<int>, kHistogramBins> bins_;
};

}  // namespace

int SearchForInitialization(const Frame& reference, const Frame& current, std::vector<Eigen::Vector2d>* previous,
                            std::vector<int>* matches, int window, double ratio, int max_level, int level_slack) {
  const size_t n = reference.size();
  matches->assign(n, -1);
  std::vector<int> distance_of_current(current.size(), 1 << 20);
  std::vector<int> reference_of_current(current.size(), -1);
  RotationHistogram histogram;
  for (size_t i = 0; i < n; ++i) {
    const int level = reference.keypoints[i].octave;
    if (level > max_level) continue;
    const Eigen::Vector2d& p = (*previous)[i];
    const std::vector<int> nearby = current.grid.InArea(p.x(), p.y(), window, current.keypoints, current.undistorted,
                                                        std::max(0, level - level_slack), level + level_slack);
    int best = 1 << 20, second = 1 << 20, best_index = -1;
    for (int j : nearby) {
      const int d =
          HammingDistance(reference.descriptors.ptr<uint8_t>(static_cast<int>(i)), current.descriptors.ptr<uint8_t>(j));
      if (distance_of_current[j] <= d) continue;
      if (d < best) {
        second = best;
        best = d;
        best_index = j;
      } else if (d < second) {
        second = d;
      }
    }
    if (best > kDescriptorDistanceLow || best >= ratio * second) continue;
    if (reference_of_current[best_index] >= 0) (*matches)[reference_of_current[best_index]] = -1;
    (*matches)[i] = best_index;
    reference_of_current[best_index] = static_cast<int>(i);
    distance_of_current[best_index] = best;
    histogram.Add(reference.keypoints[i].angle, current.keypoints[best_index].angle, static_cast<int>(i));
  }
  for (int i : histogram.Rejected()) (*matches)[i] = -1;
  int count = 0;
  for (size_t i = 0; i < n; ++i) {
    if ((*matches)[i] < 0) continue;
    (*previous)[i] = current.undistorted[(*matches)[i]];
    ++count;
  }
  return count;
}

int SearchByProjection(Frame* current, const Frame& last, const Map& map, const PinholeIntrinsics& k, double radius) {
  const Rigid3d& pose = *current->cam_from_world;
  std::vector<std::optional<Eigen::Vector2d>> predicted(last.size());
  for (size_t i = 0; i < last.size(); ++i) {
    if (!last.points[i].valid() || last.outlier[i]) continue;
    const MapPoint* point = map.FindPoint(last.points[i]);
    if (!point) continue;
    const Eigen::Vector3d in_cam = pose * point->position;
    if (in_cam.z() > 0) predicted[i] = k.Project(in_cam);
  }
  return SearchAroundPredictions(current, last, map, predicted, radius);
}

int SearchAroundPredictions(Frame* current, const Frame& last, const Map& map,
                            const std::vector<std::optional<Eigen::Vector2d>>& predicted, double radius) {
  RotationHistogram histogram;
  int matched = 0;
  for (size_t i = 0; i < last.size(); ++i) {
    if (!predicted[i] || !last.points[i].valid() || last.outlier[i]) continue;
    const MapPoint* point = map.FindPoint(last.points[i]);
    if (!point) continue;
    const Eigen::Vector2d& pixel = *predicted[i];
    const int level = last.keypoints[i].octave;
    const double r = radius * map.pyramid().scale[level];
    const std::vector<int> nearby = current->grid.InArea(pixel.x(), pixel.y(), r, current->keypoints,
                                                         current->undistorted, std::max(0, level - 1), level + 1);
    int best = 256, best_index = -1;
    for (int j : nearby) {
      if (current->points[j].valid()) continue;
      const int d = HammingDistance(point->descriptor.data(), current->descriptors.ptr<uint8_t>(j));
      if (d < best) {
        best = d;
        best_index = j;
      }
    }
    if (best > kDescriptorDistanceHigh) continue;
    current->points[best_index] = last.points[i];
    current->outlier[best_index] = 0;
    ++matched;
    histogram.Add(last.keypoints[i].angle, current->keypoints[best_index].angle, best_index);
  }
  for (int j : histogram.Rejected()) {
    current->points[j] = MapPointId();
    --matched;
  }
  return matched;
}

std::vector<std::pair<int, int>> MatchByIndex(const std::vector<cv::KeyPoint>& keypoints, const cv::Mat& descriptors,
                                              const std::vector<char>& usable, const Frame& frame,
                                              const DescriptorIndex& index, double ratio) {
  RotationHistogram histogram;
  std::vector<std::pair<int, int>> matches;
  std::vector<int> match_of(frame.size(), -1);  // frame feature -> its match so far
  std::vector<int> distance_of(frame.size(), 257);
  const auto free = [&](int j) { return !frame.points[j].valid(); };
  for (size_t i = 0; i < keypoints.size(); ++i) {
    if (!usable[i]) continue;
    const NearestDescriptors nearest = index.Nearest(descriptors.ptr<uint8_t>(static_cast<int>(i)), free);
    if (nearest.best < 0 || nearest.best_distance > kDescriptorDistanceLow ||
        nearest.best_distance >= ratio * nearest.second_distance) {
      continue;
    }
    // A frame feature goes to the closest of the features that chose it.
    const int j = nearest.best;
    if (match_of[j] >= 0) {
      if (distance_of[j] <= nearest.best_distance) continue;
      matches[match_of[j]].first = -1;
    }
    match_of[j] = static_cast<int>(matches.size());
    distance_of[j] = nearest.best_distance;
    histogram.Add(keypoints[i].angle, frame.keypoints[j].angle, static_cast<int>(matches.size()));
    matches.push_back({static_cast<int>(i), j});
  }
  for (int m : histogram.Rejected()) matches[m].first = -1;
  matches.erase(std::remove_if(matches.begin(), matches.end(), [](const auto& m) { return m.first < 0; }),
                matches.end());
  return matches;
}

int SearchByIndex(const Keyframe& keyframe, Frame* frame, const Map& map, const DescriptorIndex& index, double ratio) {
  std::vector<char> usable(keyframe.points.size(), 0);
  for (size_t i = 0; i < usable.size(); ++i)
    usable[i] = keyframe.points[i].valid() && map.FindPoint(keyframe.points[i]);
  const auto matches = MatchByIndex(keyframe.keypoints, keyframe.descriptors, usable, *frame, index, ratio);
  for (const auto& [i, j] : matches) {
    frame->points[j] = keyframe.points[i];
    frame->outlier[j] = 0;
  }
  return static_cast<int>(matches.size());
}

bool PredictInView(const MapPoint& point, const Rigid3d& cam_from_world, const PinholeIntrinsics& k, double min_x,
                   double min_y, double max_x, double max_y, const ScalePyramid& pyramid, PointInView* view) {
  const Eigen::Vector3d in_cam = cam_from_world * point.position;
  if (in_cam.z() <= 0) return false;
  const Eigen::Vector2d pixel = k.Project(in_cam);
  if (pixel.x() < min_x || pixel.x() > max_x || pixel.y() < min_y || pixel.y() > max_y) return false;
  const Eigen::Vector3d ray = point.position - cam_from_world.CentreInWorld();
  const double distance = ray.norm();
  if (distance < 0.8 * point.min_distance || distance > 1.2 * point.max_distance) return false;
  const double view_cosine = ray.dot(point.normal) / distance;
  if (view_cosine < 0.5) return false;
  view->id = point.id;
  view->pixel = pixel;
  view->predicted_level = pyramid.PredictLevel(distance, point.max_distance);
  view->view_cosine = view_cosine;
  return true;
}

int SearchByProjection(Frame* frame, const std::vector<PointInView>& points, const Map& map, double threshold,
                       double ratio) {
  int matched = 0;
  const ScalePyramid& pyramid = map.pyramid();
  for (const PointInView& view : points) {
    const MapPoint* point = map.FindPoint(view.id);
    if (!point) continue;
    // Wider windows for oblique views, where the appearance changes more.
    const double r = threshold * (view.view_cosine > 0.998 ? 2.5 : 4.0) * pyramid.scale[view.predicted_level];
    const std::vector<int> nearby =
        frame->grid.InArea(view.pixel.x(), view.pixel.y(), r, frame->keypoints, frame->undistorted,
                           view.predicted_level - 1, view.predicted_level);
    int best = 256, second = 256, best_level = -1, second_level = -1, best_index = -1;
    for (int j : nearby) {
      if (frame->points[j].valid()) continue;
      const int d = HammingDistance(point->descriptor.data(), frame->descriptors.ptr<uint8_t>(j));
      if (d < best) {
        second = best;
        second_level = best_level;
        best = d;
        best_level = frame->keypoints[j].octave;
        best_index = j;
      } else if (d < second) {
        second = d;
        second_level = frame->keypoints[j].octave;
      }
    }
    if (best > kDescriptorDistanceHigh) continue;
    if (best_level == second_level && best > ratio * second) continue;
    frame->points[best_index] = view.id;
    frame->outlier[best_index] = 0;
    ++matched;
  }
  return matched;
}

namespace {

// Features of A matched to features of B under the same vocabulary node (best under 50 bits,
// `ratio` to the second best, rotation-consistent). `usable_a` / `usable_b` say which take part.
template <class UsableA, class UsableB>
std::vector<std::pair<int, int>> MatchUnderSameNodes(const FeatureVector& nodes_a, const cv::Mat& descriptors_a,
                                                     const std::vector<cv::KeyPoint>& keypoints_a, UsableA usable_a,
                                                     const FeatureVector& nodes_b, const cv::Mat& descriptors_b,
                                                     const std::vector<cv::KeyPoint>& keypoints_b, UsableB usable_b,
                                                     double ratio) {
  RotationHistogram histogram;
  std::vector<std::pair<int, int>> matches;
  std::vector<char> taken(keypoints_b.size(), 0);
  auto a = nodes_a.nodes.begin();
  auto b = nodes_b.nodes.begin();
  while (a != nodes_a.nodes.end() && b != nodes_b.nodes.end()) {
    if (a->first < b->first) {
      ++a;
      continue;
    }
    if (b->first < a->first) {
      ++b;
      continue;
    }
    for (int i : a->second) {
      if (!usable_a(i)) continue;
      int best = 256, second = 256, best_index = -1;
      for (int j : b->second) {
        if (taken[j] || !usable_b(j)) continue;
        const int d = HammingDistance(descriptors_a.ptr<uint8_t>(i), descriptors_b.ptr<uint8_t>(j));
        if (d < best) {
          second = best;
          best = d;
          best_index = j;
        } else if (d < second) {
          second = d;
        }
      }
      if (best > kDescriptorDistanceLow || best >= ratio * second) continue;
      taken[best_index] = 1;
      histogram.Add(keypoints_a[i].angle, keypoints_b[best_index].angle, static_cast<int>(matches.size()));
      matches.push_back({i, best_index});
    }
    ++a;
    ++b;
  }
  std::vector<char> rejected(matches.size(), 0);
  for (int m : histogram.Rejected()) rejected[m] = 1;
  std::vector<std::pair<int, int>> kept;
  for (size_t m = 0; m < matches.size(); ++m) {
    if (!rejected[m]) kept.push_back(matches[m]);
  }
  return kept;
}

}  // namespace

int SearchByBow(const Keyframe& keyframe, Frame* frame, const Map& map, double ratio) {
  const auto has_point = [&](int i) { return keyframe.points[i].valid() && map.FindPoint(keyframe.points[i]); };
  const auto free = [&](int j) { return !frame->points[j].valid(); };
  const auto matches = MatchUnderSameNodes(keyframe.bow_features, keyframe.descriptors, keyframe.keypoints, has_point,
                                           frame->bow_features, frame->descriptors, frame->keypoints, free, ratio);
  for (const auto& [i, j] : matches) {
    frame->points[j] = keyframe.points[i];
    frame->outlier[j] = 0;
  }
  return static_cast<int>(matches.size());
}

std::vector<std::pair<int, int>> MatchKeyframesByBow(const Keyframe& a, const Map& map_a, const Keyframe& b,
                                                     const Map& map_b, double ratio) {
  const auto in_a = [&](int i) { return a.points[i].valid() && map_a.FindPoint(a.points[i]); };
  const auto in_b = [&](int j) { return b.points[j].valid() && map_b.FindPoint(b.points[j]); };
  return MatchUnderSameNodes(a.bow_features, a.descriptors, a.keypoints, in_a, b.bow_features, b.descriptors,
                             b.keypoints, in_b, ratio);
}

Eigen::Matrix3d FundamentalMatrix(const Rigid3d& cam1_from_world, const Rigid3d& cam2_from_world,
                                  const PinholeIntrinsics& k) {
  const Eigen::Matrix3d k_inv = k.K().inverse();
  return k_inv.transpose() * (cam2_from_world * cam1_from_world.Inverse()).EssentialMatrix() * k_inv;
}

std::vector<std::pair<int, int>> SearchForTriangulation(const Keyframe& kf1, const Keyframe& kf2,
                                                        const Eigen::Matrix3d& f21, const PinholeIntrinsics& k,
                                                        const ScalePyramid& pyramid) {
  // The epipole: kf1's centre seen by kf2. Matches too close to it are unreliable.
  const Eigen::Vector3d c1_in_2 = kf2.cam_from_world * kf1.Centre();
  const bool epipole_in_front = c1_in_2.z() > 0;
  const Eigen::Vector2d epipole = epipole_in_front ? k.Project(c1_in_2) : Eigen::Vector2d(0, 0);
  std::vector<int> match_of_1(kf1.keypoints.size(), -1);
  std::vector<char> taken2(kf2.keypoints.size(), 0);
  RotationHistogram histogram;
  auto a = kf1.bow_features.nodes.begin();
  auto b = kf2.bow_features.nodes.begin();
  while (a != kf1.bow_features.nodes.end() && b != kf2.bow_features.nodes.end()) {
    if (a->first < b->first) {
      ++a;
      continue;
    }
    if (b->first < a->first) {
      ++b;
      continue;
    }
    for (int i : a->second) {
      if (kf1.points[i].valid()) continue;
      const Eigen::Vector3d line = f21 * kf1.undistorted[i].homogeneous();
      const double line_norm2 = line.head<2>().squaredNorm();
      if (line_norm2 < 1e-18) continue;
      int best = kDescriptorDistanceLow + 1, best_index = -1;
      for (int j : b->second) {
        if (kf2.points[j].valid() || taken2[j]) continue;
        const int d = HammingDistance(kf1.descriptors.ptr<uint8_t>(i), kf2.descriptors.ptr<uint8_t>(j));
        if (d >= best) continue;
        const Eigen::Vector2d& x2 = kf2.undistorted[j];
        if (epipole_in_front && (x2 - epipole).squaredNorm() < 100 * pyramid.scale[kf2.keypoints[j].octave]) continue;
        const double distance2 = std::pow(line.dot(x2.homogeneous()), 2) / line_norm2;
        if (distance2 >= 3.84 * pyramid.sigma2[kf2.keypoints[j].octave]) continue;
        best = d;
        best_index = j;
      }
      if (best_index < 0) continue;
      match_of_1[i] = best_index;
      taken2[best_index] = 1;
      histogram.Add(kf1.keypoints[i].angle, kf2.keypoints[best_index].angle, i);
    }
    ++a;
    ++b;
  }
  for (int i : histogram.Rejected()) match_of_1[i] = -1;
  std::vector<std::pair<int, int>> pairs;
  for (size_t i = 0; i < match_of_1.size(); ++i) {
    if (match_of_1[i] >= 0) pairs.push_back({static_cast<int>(i), match_of_1[i]});
  }
  return pairs;
}

int Fuse(Map* map, KeyframeId keyframe_id, const std::vector<MapPointId>& candidates, const PinholeIntrinsics& k,
         double radius, FuseSearch search) {
  Keyframe* keyframe = map->FindKeyframe(keyframe_id);
  if (!keyframe) return 0;
  const ScalePyramid& pyramid = map->pyramid();
  const Eigen::Vector3d centre = keyframe->Centre();
  int fused = 0;
  for (MapPointId id : candidates) {
    const MapPoint* point = map->FindPoint(id);
    if (!point || point->observations.count(keyframe_id)) continue;
    const Eigen::Vector3d in_cam = keyframe->cam_from_world * point->position;
    if (in_cam.z() <= 0) continue;
    const Eigen::Vector2d pixel = k.Project(in_cam);
    const Eigen::Vector3d ray = point->position - centre;
    const double distance = ray.norm();
    if (distance < 0.8 * point->min_distance || distance > 1.2 * point->max_distance) continue;
    if (ray.dot(point->normal) < 0.5 * distance) continue;
    const int level = pyramid.PredictLevel(distance, point->max_distance);
    const double r = radius * pyramid.scale[level];
    const std::vector<int> nearby =
        keyframe->grid.InArea(pixel.x(), pixel.y(), r, keyframe->keypoints, keyframe->undistorted);
    int best = 256, best_index = -1;
    for (int j : nearby) {
      const int feature_level = keyframe->keypoints[j].octave;
      if (feature_level < level - 1 || feature_level > level) continue;
      if (search == FuseSearch::kWithinNoise &&
          (keyframe->undistorted[j] - pixel).squaredNorm() * pyramid.inverse_sigma2[feature_level] > 5.99) {
        continue;
      }
      const int d = HammingDistance(point->descriptor.data(), keyframe->descriptors.ptr<uint8_t>(j));
      if (d < best) {
        best = d;
        best_index = j;
      }
    }
    if (best > kDescriptorDistanceLow) continue;
    const MapPointId existing = keyframe->points[best_index];
    if (existing.valid() && map->FindPoint(existing)) {
      const MapPoint* other = map->FindPoint(existing);
      if (other->observations.size() > point->observations.size()) {
        map->ReplacePoint(id, existing);
      } else {
        map->ReplacePoint(existing, id);
      }
    } else {
      map->AddObservation(keyframe_id, best_index, id);
    }
    ++fused;
  }
  return fused;
}

}  // namespace stitch
