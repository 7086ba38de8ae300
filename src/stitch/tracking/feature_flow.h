#pragma once
// Frames between keyframes for less: instead of extracting ORB features from every frame, the map
// points tracked in the last frame that was extracted (the flow's source) are followed into the
// new image by pyramidal Lucas-Kanade optical flow, each started where the predicted pose
// projects its point. Following from the source (not from the last followed frame) keeps the
// positions from drifting over a run of followed frames. A followed frame has positions and map
// points but no descriptors: it is placed by pose optimization and never becomes a keyframe; the
// tracker extracts a frame again wherever one might become a keyframe (docs/speed.md).

#include <optional>
#include <vector>

#include <opencv2/core.hpp>

#include "stitch/geometry/camera.h"
#include "stitch/geometry/rigid3.h"
#include "stitch/map/frame.h"
#include "stitch/map/map.h"
#include "stitch/tracking/tracking_options.h"

namespace stitch {

class FeatureFlow {
 public:
  explicit FeatureFlow(const FeatureFlowOptions& options);

  // `frame` (extracted from `image`, CV_8UC1, and tracked) becomes the source: its tracked
  // features that are not outliers. Its image pyramid is built here.
  void KeepSource(const cv::Mat& image, const Frame& frame);
  void Clear();
  bool has_source() const { return source_frame_index_ >= 0; }
  int source_frame_index() const { return source_frame_index_; }
  int source_points() const { return static_cast<int>(positions_.size()); }

  // The source's points followed into `image`: a frame with their positions (keypoints at the
  // source feature's level, undistorted by `undistorter`), its map points, no descriptors, and
  // the pose `predicted`; the points whose flow failed or projects outside are left out, and
  // those whose depth the predicted pose changes by more than `max_scale_change` of the source's
  // (their patch grew or shrank by that much, which a shifted window does not follow).
  Frame Follow(const cv::Mat& image, int frame_index, int64_t t_ns, const Map& map, const Rigid3d& predicted,
               const Camera& camera, const Undistorter& undistorter) const;

 private:
  FeatureFlowOptions options_;
  int source_frame_index_ = -1;
  std::optional<Rigid3d> source_cam_from_world_;
  std::vector<cv::Mat> pyramid_;  // the source image's, with derivatives
  std::vector<cv::Point2f> positions_;
  std::vector<MapPointId> points_;
  std::vector<int> octaves_;
};

}  // namespace stitch
