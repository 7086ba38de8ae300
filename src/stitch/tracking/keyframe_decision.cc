#include "stitch/tracking/keyframe_decision.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace stitch {

int ReferencePoints(const Map& map, const Keyframe& reference) {
  const int min_observations = map.num_keyframes() <= 2 ? 2 : 3;
  int count = 0;
  for (MapPointId p : reference.points) {
    const MapPoint* point = p.valid() ? map.FindPoint(p) : nullptr;
    if (point && static_cast<int>(point->observations.size()) >= min_observations) ++count;
  }
  return count;
}

double MedianParallaxDeg(const Map& map, const Keyframe& reference, const Frame& frame) {
  if (!frame.cam_from_world) return -1;
  const Eigen::Vector3d from_reference = reference.cam_from_world.CentreInWorld();
  const Eigen::Vector3d from_frame = frame.cam_from_world->CentreInWorld();
  std::vector<double> cosines;
  cosines.reserve(frame.points.size());
  for (size_t i = 0; i < frame.points.size(); ++i) {
    if (!frame.points[i].valid() || frame.outlier[i]) continue;
    const MapPoint* point = map.FindPoint(frame.points[i]);
    if (!point) continue;
    const Eigen::Vector3d a = point->position - from_reference, b = point->position - from_frame;
    const double norms = a.norm() * b.norm();
    if (norms > 0) cosines.push_back(a.dot(b) / norms);
  }
  if (cosines.empty()) return -1;
  // The median angle is the median cosine's angle (the cosine falls as the angle grows).
  const auto middle = cosines.begin() + static_cast<std::ptrdiff_t>(cosines.size() / 2);
  std::nth_element(cosines.begin(), middle, cosines.end());
  return std::acos(std::clamp(*middle, -1.0, 1.0)) * 180.0 / M_PI;
}

double MotionAxisAngleDeg(const Keyframe& reference, const Frame& frame) {
  if (!frame.cam_from_world) return -1;
  const Eigen::Vector3d displacement = frame.cam_from_world->CentreInWorld() - reference.cam_from_world.CentreInWorld();
  const double length = displacement.norm();
  if (!(length > 0)) return -1;
  // The optical axis in the world: the camera's z axis, the rotation's third row.
  const Eigen::Vector3d axis = frame.cam_from_world->RotationMatrix().row(2).transpose();
  return std::acos(std::clamp(std::abs(axis.dot(displacement)) / length, 0.0, 1.0)) * 180.0 / M_PI;
}

namespace {

bool MovesAlongAxis(const KeyframeDecisionInput& input, const TrackingOptions& options) {
  return input.motion_axis_angle_deg >= 0 && input.motion_axis_angle_deg <= options.keyframe_along_axis_max_angle_deg;
}

}  // namespace

double KeyframeRatio(const KeyframeDecisionInput& input, const TrackingOptions& options) {
  return MovesAlongAxis(input, options) ? options.keyframe_ratio_along_axis : options.keyframe_ratio;
}

double TrackedCoverage(const Frame& frame, int width, int height) {
  constexpr int kCols = 8, kRows = 6;
  if (width <= 0 || height <= 0) return -1;
  int features[kCols * kRows] = {}, tracked[kCols * kRows] = {};
  for (size_t i = 0; i < frame.size(); ++i) {
    const cv::Point2f& p = frame.keypoints[i].pt;
    const int col = std::clamp(static_cast<int>(p.x * kCols / width), 0, kCols - 1);
    const int row = std::clamp(static_cast<int>(p.y * kRows / height), 0, kRows - 1);
    ++features[row * kCols + col];
    if (frame.points[i].valid() && !frame.outlier[i]) ++tracked[row * kCols + col];
  }
  int cells = 0, covered = 0;
  for (int c = 0; c < kCols * kRows; ++c) {
    if (features[c] < 3) continue;
    ++cells;
    covered += tracked[c] > 0;
  }
  return cells > 0 ? static_cast<double>(covered) / cells : -1;
}

bool NeedKeyframe(const KeyframeDecisionInput& input, const TrackingOptions& options, double fps) {
  if (!input.has_reference) return true;
  const int max_gap = options.max_keyframe_gap > 0 ? options.max_keyframe_gap : static_cast<int>(std::lround(fps));
  const bool long_gap = input.frames_since_keyframe >= max_gap;
  bool few_tracked =
      input.tracked_points < options.keyframe_ratio * input.reference_points && input.tracked_points > 15;
  // A frame that moved too little from its reference to triangulate much (a camera that mostly
  // rotates) becomes a keyframe at the pace a mapper can take (once
  // keyframe_gap_without_parallax_s has passed since the last), or at once when it sees much new
  // ground: it tracks fewer than keyframe_ratio_without_parallax of the reference's points.
  if (few_tracked && options.keyframe_min_parallax_deg > 0 && input.parallax_deg >= 0 &&
      input.parallax_deg < options.keyframe_min_parallax_deg) {
    const bool paced = options.keyframe_gap_without_parallax_s > 0 &&
                       input.frames_since_keyframe >= options.keyframe_gap_without_parallax_s * fps;
    few_tracked = paced || input.tracked_points < options.keyframe_ratio_without_parallax * input.reference_points;
  }
  // A camera that moves along its viewing direction (a forward camera) and so has parallax keeps
  // more of its reference's points: they leave its view at every edge and grow as it nears them.
  if (!few_tracked && MovesAlongAxis(input, options) && input.tracked_points > 15 &&
      input.tracked_points < options.keyframe_ratio_along_axis * input.reference_points &&
      (options.keyframe_min_parallax_deg <= 0 || input.parallax_deg >= options.keyframe_min_parallax_deg)) {
    few_tracked = true;
  }
  // Much of the view is ground the map does not hold (the camera moved on while it was lost,
  // or turned): a keyframe maps it, whatever the ratio says.
  if (!few_tracked && options.keyframe_min_coverage > 0 && input.tracked_coverage >= 0 &&
      input.tracked_coverage < options.keyframe_min_coverage && input.tracked_points > 15 &&
      input.parallax_deg >= options.keyframe_coverage_min_parallax_deg) {
    few_tracked = true;
  }
  // As built: a long gap alone never makes a keyframe while the mapper is busy, and with the
  // mapper ready the gap does not matter, so the decision is few_tracked && mapper_ready.
  return (long_gap || input.mapper_ready) && few_tracked && input.mapper_ready;
}

}  // namespace stitch
