#include "stitch/tracking/rolling_shutter.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Dense>
#include <Eigen/Geometry>

namespace stitch {

double UnrollRollingShutter(Frame* frame, const Rigid3d& velocity, double velocity_interval_s, double line_delay_s,
                            const InverseDepthPlane& depth, const Undistorter& undistorter) {
  if (!(velocity_interval_s > 0 && line_delay_s > 0 && depth.valid())) return 0;
  const Camera& camera = undistorter.camera();
  const Eigen::AngleAxisd turn(velocity.rotation);
  // The motion per second: rotation vector and translation (of points in the camera).
  const Eigen::Vector3d w = turn.angle() * turn.axis() / velocity_interval_s;
  const Eigen::Vector3d v = velocity.translation / velocity_interval_s;
  const double fx = camera.fx(), fy = camera.fy(), cx = camera.cx(), cy = camera.cy();
  const double max_x = camera.width() - 1, max_y = camera.height() - 1;
  double largest = 0;
  for (size_t i = 0; i < frame->size(); ++i) {
    cv::KeyPoint& keypoint = frame->keypoints[i];
    const double delay = keypoint.pt.y * line_delay_s;  // its row was read this long after the first
    const Eigen::Vector2d& u = frame->undistorted[i];
    // The point's ray at unit depth, and its inverse depth: P = ray / inverse_depth.
    const Eigen::Vector3d ray((u.x() - cx) / fx, (u.y() - cy) / fy, 1.0);
    const double inverse_depth = depth.At(ray.x(), ray.y());
    // Where it was at the first row's time, back by the motion over the delay, at unit depth:
    // ray - delay * (w x ray + v * inverse_depth).
    const Eigen::Vector3d before = ray - delay * (w.cross(ray) + inverse_depth * v);
    if (before.z() <= 0) continue;
    const std::optional<Eigen::Vector2d> pixel = camera.Project(before);
    if (!pixel) continue;
    const float x = static_cast<float>(std::round(std::clamp(pixel->x(), 0.0, max_x) * 8.0) / 8.0);
    const float y = static_cast<float>(std::round(std::clamp(pixel->y(), 0.0, max_y) * 8.0) / 8.0);
    largest = std::max(largest, static_cast<double>(std::hypot(x - keypoint.pt.x, y - keypoint.pt.y)));
    keypoint.pt = cv::Point2f(x, y);
    frame->undistorted[i] = undistorter.Undistort(x, y);
  }
  frame->grid = FeatureGrid(frame->undistorted, undistorter);
  return largest;
}

InverseDepthPlane FitInverseDepthPlane(const Map& map, const Frame& frame) {
  InverseDepthPlane plane;
  if (!frame.cam_from_world) return plane;
  std::vector<Eigen::Vector3d> samples;  // x, y, 1/z
  for (size_t i = 0; i < frame.points.size(); ++i) {
    if (!frame.points[i].valid() || frame.outlier[i]) continue;
    if (const MapPoint* point = map.FindPoint(frame.points[i])) {
      const Eigen::Vector3d p = *frame.cam_from_world * point->position;
      if (p.z() > 0) samples.emplace_back(p.x() / p.z(), p.y() / p.z(), 1.0 / p.z());
    }
  }
  const auto fit = [&](const std::vector<Eigen::Vector3d>& used) {
    Eigen::MatrixXd a(used.size(), 3);
    Eigen::VectorXd b(used.size());
    for (size_t i = 0; i < used.size(); ++i) {
      a.row(static_cast<Eigen::Index>(i)) << used[i].x(), used[i].y(), 1.0;
      b(static_cast<Eigen::Index>(i)) = used[i].z();
    }
    return Eigen::Vector3d(a.colPivHouseholderQr().solve(b));
  };
  if (samples.size() < 10) return plane;
  Eigen::Vector3d abc = fit(samples);
  // Once more without the quarter farthest from the first fit (buildings above flat ground).
  std::vector<double> residuals;
  for (const auto& s : samples) residuals.push_back(std::abs(abc.dot(Eigen::Vector3d(s.x(), s.y(), 1)) - s.z()));
  std::vector<double> sorted = residuals;
  const auto cut = sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() * 3 / 4);
  std::nth_element(sorted.begin(), cut, sorted.end());
  std::vector<Eigen::Vector3d> kept;
  for (size_t i = 0; i < samples.size(); ++i) {
    if (residuals[i] <= *cut) kept.push_back(samples[i]);
  }
  if (kept.size() >= 10) abc = fit(kept);
  plane.a = abc.x();
  plane.b = abc.y();
  plane.c = abc.z();
  plane.min = 0;
  for (const auto& s : samples) plane.max = std::max(plane.max, s.z());
  return plane;
}

}  // namespace stitch
