#pragma once
// Frames of the synthetic flight with exact poses and depth, and one-keyframe maps made from
// them: the known answer for matching tests and benchmarks. For tests and benchmarks only.

#include <memory>

#include "stitch/map/frame.h"
#include "stitch/map/map.h"
#include "stitch/synthetic/synthetic_sequence.h"

namespace stitch::testing {

class RenderedViews {
 public:
  // One 200-frame strip of the default flight (about 230 m).
  RenderedViews() {
    SyntheticOptions options;
    options.flight.num_frames = 200;
    options.flight.num_strips = 1;
    options.flight.strip_length_m = 200;
    sequence_ = std::make_unique<SyntheticSequence>(options, FailureSchedule());
    undistorter_ = Undistorter(sequence_->camera());
    k_ = sequence_->camera().Intrinsics();
  }

  const PinholeIntrinsics& k() const { return k_; }

  // Frame `index` with its features and true pose; its depth image when asked.
  Frame Render(int index, cv::Mat* depth = nullptr) {
    const cv::Mat image = sequence_->RenderFrame(index, depth);
    Frame frame = MakeFrame(image, index, sequence_->flight().TimestampNs(index), &extractor_, undistorter_);
    frame.cam_from_world = sequence_->flight().WorldFromCam(index).Inverse();
    return frame;
  }

  // A map with one keyframe (`frame`) whose features at known depth become points.
  Map MapFromFrame(const Frame& frame, const cv::Mat& depth, Keyframe* out) const {
    Map map(MakeSubmapId(0, 1), ScalePyramid::From(OrbOptions()));
    Keyframe keyframe = KeyframeFromFrame(frame, MakeKeyframeId(map.id(), 0));
    const Rigid3d world_from_cam = frame.cam_from_world->Inverse();
    for (size_t i = 0; i < frame.size(); ++i) {
      const float z = depth.at<float>(cvRound(frame.keypoints[i].pt.y), cvRound(frame.keypoints[i].pt.x));
      if (z <= 0) continue;
      MapPoint point;
      point.id = map.NewPointId();
      const Eigen::Vector2d n = k_.Normalize(frame.undistorted[i]);
      point.position = world_from_cam * Eigen::Vector3d(n.x() * z, n.y() * z, z);
      point.descriptor = ToDescriptor(frame.descriptors.ptr<uint8_t>(static_cast<int>(i)));
      keyframe.points[i] = point.id;
      map.AddPoint(point);
    }
    *out = keyframe;
    map.AddKeyframe(keyframe);
    for (const auto& [id, p] : map.points()) map.UpdatePointGeometry(id);
    return map;
  }

  // Fraction of the frame's matches whose point projects within `tolerance` px of the feature
  // at the frame's true pose; `count`: the matches.
  double Consistency(const Frame& frame, const Map& map, double tolerance, int* count) const {
    int good = 0;
    *count = 0;
    for (size_t i = 0; i < frame.size(); ++i) {
      if (!frame.points[i].valid()) continue;
      ++*count;
      const Eigen::Vector2d pixel = k_.Project(*frame.cam_from_world * map.FindPoint(frame.points[i])->position);
      good += (pixel - frame.undistorted[i]).norm() < tolerance;
    }
    return *count ? static_cast<double>(good) / *count : 0;
  }

 private:
  std::unique_ptr<SyntheticSequence> sequence_;
  Undistorter undistorter_;
  OrbExtractor extractor_{OrbOptions{}};
  PinholeIntrinsics k_;
};

}  // namespace stitch::testing
