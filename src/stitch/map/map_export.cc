#include "stitch/map/map_export.h"

#include <algorithm>
#include <cmath>
#include <map>

#include "stitch/util/error.h"
#include "stitch/util/statistics.h"

namespace stitch {

bool MapExportOptions::Check(std::string* why) const {
  if (min_observations < 0) {
    if (why) *why = "merger.map_export.min_observations must be >= 0";
    return false;
  }
  if (!(max_extent_ratio >= 1)) {
    if (why) *why = "merger.map_export.max_extent_ratio must be >= 1";
    return false;
  }
  return true;
}

namespace {}  // namespace

std::vector<bool> PointsToExport(const std::vector<Eigen::Vector3d>& positions, const std::vector<int>& observations,
                                 const MapExportOptions& options) {
  if (positions.size() != observations.size()) throw Error("PointsToExport: one observation count per point");
  std::vector<bool> keep(positions.size(), false);
  std::vector<size_t> seen;
  for (size_t i = 0; i < positions.size(); ++i) {
    if (observations[i] >= options.min_observations && positions[i].allFinite()) seen.push_back(i);
  }
  if (seen.empty()) return keep;
  // The centre: the per-axis median, which the far points do not move.
  Eigen::Vector3d centre;
  for (int axis = 0; axis < 3; ++axis) {
    std::vector<double> values;
    values.reserve(seen.size());
    for (size_t i : seen) values.push_back(positions[i][axis]);
    centre[axis] = Median(std::move(values));
  }
  std::vector<double> distances;
  distances.reserve(seen.size());
  for (size_t i : seen) distances.push_back((positions[i] - centre).norm());
  std::vector<double> sorted = distances;
  const auto p90 = sorted.begin() + static_cast<long>(0.9 * (sorted.size() - 1));
  std::nth_element(sorted.begin(), p90, sorted.end());
  const double limit = options.max_extent_ratio * *p90;
  for (size_t k = 0; k < seen.size(); ++k) keep[seen[k]] = distances[k] <= limit;
  return keep;
}

ColmapModel ColmapModelOf(const Map& map, const std::function<const Camera*(const Keyframe&)>& camera_of,
                          const MapExportOptions& options, const std::function<std::string(const Keyframe&)>& name) {
  ColmapModel model;
  // Images in frame order, ids from 1.
  std::vector<const Keyframe*> keyframes;
  for (const auto& [id, keyframe] : map.keyframes()) keyframes.push_back(&keyframe);
  std::sort(keyframes.begin(), keyframes.end(), [](const Keyframe* a, const Keyframe* b) {
    return a->frame_index != b->frame_index ? a->frame_index < b->frame_index : a->id.value < b->id.value;
  });
  std::map<KeyframeId, size_t> image_of;
  for (const Keyframe* keyframe : keyframes) {
    const Camera* camera = camera_of(*keyframe);
    if (!camera) continue;
    int camera_id = 0;
    for (const auto& [id, known] : model.cameras) {
      if (known.model() == camera->model() && known.width() == camera->width() && known.height() == camera->height() &&
          known.params() == camera->params()) {
        camera_id = id;
      }
    }
    if (camera_id == 0) {
      camera_id = static_cast<int>(model.cameras.size()) + 1;
      model.cameras.emplace(camera_id, *camera);
    }
    ColmapImage image;
    image.id = static_cast<int>(model.images.size()) + 1;
    image.camera_id = camera_id;
    image.cam_from_world = keyframe->cam_from_world;
    image.name = name(*keyframe);
    for (const cv::KeyPoint& k : keyframe->keypoints) image.features.emplace_back(k.pt.x, k.pt.y);
    image.point_ids.assign(image.features.size(), -1);
    image_of[keyframe->id] = model.images.size();
    model.images.push_back(std::move(image));
  }
  // Points: those worth exporting, in a fixed order, with the observations of keyframes here.
  std::vector<const MapPoint*> points;
  for (const auto& [id, point] : map.points()) points.push_back(&point);
  std::sort(points.begin(), points.end(),
            [](const MapPoint* a, const MapPoint* b) { return a->id.value < b->id.value; });
  std::vector<Eigen::Vector3d> positions;
  std::vector<int> observations;
  for (const MapPoint* point : points) {
    positions.push_back(point->position);
    observations.push_back(static_cast<int>(point->observations.size()));
  }
  const std::vector<bool> keep = PointsToExport(positions, observations, options);
  for (size_t i = 0; i < points.size(); ++i) {
    if (!keep[i]) continue;
    ColmapPoint point;
    point.id = static_cast<int64_t>(model.points.size()) + 1;
    point.position = points[i]->position;
    for (const auto& [keyframe, feature] : points[i]->observations) {
      const auto image = image_of.find(keyframe);
      if (image == image_of.end() || feature < 0 ||
          feature >= static_cast<int>(model.images[image->second].features.size()) ||
          model.images[image->second].point_ids[feature] != -1) {
        continue;  // a keyframe this map does not hold, or a feature already given to another point
      }
      point.track.push_back({model.images[image->second].id, feature});
    }
    if (point.track.size() < 2) continue;
    for (const auto& [image_id, feature] : point.track) model.images[image_id - 1].point_ids[feature] = point.id;
    model.points.push_back(std::move(point));
  }
  SetReprojectionErrors(&model);
  return model;
}

}  // namespace stitch
