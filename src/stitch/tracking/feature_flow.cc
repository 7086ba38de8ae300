#include "stitch/tracking/feature_flow.h"

#include <opencv2/video/tracking.hpp>

namespace stitch {

FeatureFlow::FeatureFlow(const FeatureFlowOptions& options) : options_(options) {}

void FeatureFlow::Clear() {
  source_frame_index_ = -1;
  source_cam_from_world_.reset();
  pyramid_.clear();
  positions_.clear();
  points_.clear();
  octaves_.clear();
}

void FeatureFlow::KeepSource(const cv::Mat& image, const Frame& frame) {
  Clear();
  for (size_t i = 0; i < frame.size(); ++i) {
    if (!frame.points[i].valid() || frame.outlier[i]) continue;
    positions_.push_back(frame.keypoints[i].pt);
    points_.push_back(frame.points[i]);
    octaves_.push_back(frame.keypoints[i].octave);
  }
  const cv::Size window(options_.window_px, options_.window_px);
  cv::buildOpticalFlowPyramid(image, pyramid_, window, options_.levels, /*withDerivatives=*/true);
  source_frame_index_ = frame.frame_index;
  source_cam_from_world_ = frame.cam_from_world;
}

Frame FeatureFlow::Follow(const cv::Mat& image, int frame_index, int64_t t_ns, const Map& map, const Rigid3d& predicted,
                          const Camera& camera, const Undistorter& undistorter) const {
  Frame frame;
  frame.frame_index = frame_index;
  frame.t_ns = t_ns;
  frame.cam_from_world = predicted;
  if (!has_source() || positions_.empty()) return frame;
  // Each flow starts where the predicted pose projects its point (else where the source saw it).
  std::vector<cv::Point2f> guesses(positions_);
  std::vector<const MapPoint*> found(points_.size());  // null: culled since the source
  for (size_t i = 0; i < points_.size(); ++i) {
    const MapPoint* point = found[i] = map.FindPoint(points_[i]);
    if (!point) continue;
    const Eigen::Vector3d in_camera = predicted * point->position;
    if (source_cam_from_world_ && options_.max_scale_change > 0) {
      // Lucas-Kanade shifts its window; a patch that grows or shrinks is not followed.
      const double source_depth = (*source_cam_from_world_ * point->position).z();
      if (!(in_camera.z() > 0) || !(std::abs(source_depth / in_camera.z() - 1.0) <= options_.max_scale_change)) {
        found[i] = nullptr;
        continue;
      }
    }
    const std::optional<Eigen::Vector2d> pixel = camera.Project(in_camera);
    if (pixel && camera.InImage(*pixel)) guesses[i] = cv::Point2f(pixel->x(), pixel->y());
  }
  std::vector<uchar> status;
  std::vector<float> error;
  const cv::Size window(options_.window_px, options_.window_px);
  cv::calcOpticalFlowPyrLK(pyramid_, image, positions_, guesses, status, error, window, options_.levels,
                           cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 20, 0.03),
                           cv::OPTFLOW_USE_INITIAL_FLOW);
  for (size_t i = 0; i < positions_.size(); ++i) {
    if (!status[i] || !(error[i] <= options_.max_error)) continue;
    const Eigen::Vector2d pixel(guesses[i].x, guesses[i].y);
    if (!found[i] || !camera.InImage(pixel, 1.0)) continue;
    cv::KeyPoint keypoint(guesses[i], 31.0f);
    keypoint.octave = octaves_[i];
    frame.keypoints.push_back(keypoint);
    frame.undistorted.push_back(undistorter.Undistort(pixel.x(), pixel.y()));
    frame.points.push_back(points_[i]);
    frame.outlier.push_back(0);
  }
  return frame;
}

}  // namespace stitch
