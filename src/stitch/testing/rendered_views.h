#pragma once
// Frames of a synthetic flight with exact poses and depth, and maps made from them: the known
// answer for the stage tests of matching, tracking and mapping, and for benchmarks. For tests and
// benchmarks only.

#include <memory>

#include "stitch/map/frame.h"
#include "stitch/map/map.h"
#include "stitch/map/matcher.h"
#include "stitch/map/view_geometry.h"
#include "stitch/synthetic/synthetic_sequence.h"

namespace stitch::testing {

class RenderedViews {
 public:
  // One 200-frame strip of the default flight (200 m at 70 m above the terrain).
  RenderedViews() : RenderedViews(Strip(200, 200.0)) {}
  explicit RenderedViews(const SyntheticOptions& options) {
    sequence_ = std::make_unique<SyntheticSequence>(options, FailureSchedule());
    geometry_ = ViewGeometry(sequence_->camera(), ScalePyramid::From(OrbOptions()));
  }

  // A straight strip of `frames` frames of the default flight, `length_m` long (by default at
  // the default flight's speed, 1.15 m a frame).
  static SyntheticOptions Strip(int frames, double length_m = 0) {
    SyntheticOptions options;
    options.flight.num_frames = frames;
    options.flight.num_strips = 1;
    options.flight.strip_length_m = length_m > 0 ? length_m : 1.15 * frames;
    return options;
  }

  const PinholeIntrinsics& k() const { return geometry_.intrinsics; }
  const ViewGeometry& geometry() const { return geometry_; }
  const SyntheticSequence& sequence() const { return *sequence_; }
  Rigid3d WorldFromCam(int index) const { return sequence_->flight().WorldFromCam(index); }

  // Frame `index` of the flight with its features and true pose; its depth image when asked.
  Frame Render(int index, cv::Mat* depth = nullptr) {
    const cv::Mat image = sequence_->RenderFrame(index, depth);
    Frame frame = MakeFrame(image, index, sequence_->flight().TimestampNs(index), &extractor_, geometry_.undistorter);
    frame.cam_from_world = WorldFromCam(index).Inverse();
    return frame;
  }

  // The world seen from any pose, as frame `index` (its sensor noise and timestamp), with its
  // features and that pose; `extractor` (optional) instead of the default ORB settings.
  Frame RenderPose(const Rigid3d& world_from_cam, int index, cv::Mat* depth = nullptr,
                   OrbExtractor* extractor = nullptr) {
    const cv::Mat image = sequence_->RenderAt(world_from_cam, static_cast<uint64_t>(index), depth);
    Frame frame = MakeFrame(image, index, sequence_->flight().TimestampNs(index), extractor ? extractor : &extractor_,
                            geometry_.undistorter);
    frame.cam_from_world = world_from_cam.Inverse();
    return frame;
  }

  // A map with one keyframe (`frame`) whose features at known depth become points.
  Map MapFromFrame(const Frame& frame, const cv::Mat& depth, Keyframe* out) const {
    Map map(MakeSubmapId(0, 1), geometry_.pyramid);
    Keyframe keyframe = KeyframeFromFrame(frame, MakeKeyframeId(map.id(), 0));
    const Rigid3d world_from_cam = frame.cam_from_world->Inverse();
    for (size_t i = 0; i < frame.size(); ++i) {
      const float z = depth.at<float>(cvRound(frame.keypoints[i].pt.y), cvRound(frame.keypoints[i].pt.x));
      if (z <= 0) continue;
      MapPoint point;
      point.id = map.NewPointId();
      const Eigen::Vector2d n = k().Normalize(frame.undistorted[i]);
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

  // Adds `frame` (at its true pose) to `map` as keyframe number `number`: its features that
  // match the map's points by projection observe them (at most `max_matches`), the others with
  // depth (every `new_point_stride`-th of them) become new points. Returns the keyframe's id.
  KeyframeId AddKeyframe(Map* map, Frame frame, const cv::Mat& depth, int number, int new_point_stride = 1,
                         int max_matches = 1 << 30) const {
    std::vector<PointInView> in_view;
    for (const auto& [id, point] : map->points()) {
      PointInView view;
      if (geometry_.InView(point, *frame.cam_from_world, &view)) in_view.push_back(view);
    }
    std::fill(frame.points.begin(), frame.points.end(), MapPointId());
    SearchByProjection(&frame, in_view, *map, 1.0);
    int matches = 0;
    for (MapPointId& p : frame.points) {
      if (p.valid() && ++matches > max_matches) p = MapPointId();
    }
    const KeyframeId id = MakeKeyframeId(map->id(), static_cast<uint32_t>(number));
    Keyframe keyframe = KeyframeFromFrame(frame, id);
    const Rigid3d world_from_cam = frame.cam_from_world->Inverse();
    int unmatched = 0;
    for (size_t i = 0; i < frame.size(); ++i) {
      if (keyframe.points[i].valid()) continue;
      const float z = depth.at<float>(cvRound(frame.keypoints[i].pt.y), cvRound(frame.keypoints[i].pt.x));
      if (z <= 0 || unmatched++ % new_point_stride != 0) continue;
      MapPoint point;
      point.id = map->NewPointId();
      const Eigen::Vector2d n = k().Normalize(frame.undistorted[i]);
      point.position = world_from_cam * Eigen::Vector3d(n.x() * z, n.y() * z, z);
      point.reference_keyframe = id;
      point.first_keyframe = id;
      keyframe.points[i] = point.id;
      map->AddPoint(point);
    }
    map->AddKeyframe(keyframe);
    for (MapPointId p : map->FindKeyframe(id)->points) {
      if (!p.valid()) continue;
      map->UpdatePointAppearance(p);
      map->UpdatePointGeometry(p);
    }
    map->UpdateConnections(id);
    return id;
  }

  // Fraction of the frame's matches whose point projects within `tolerance` px of the feature
  // at the frame's true pose; `count`: the matches.
  double Consistency(const Frame& frame, const Map& map, double tolerance, int* count) const {
    return ConsistencyAt(frame, map, *frame.cam_from_world, tolerance, count);
  }
  double ConsistencyAt(const Frame& frame, const Map& map, const Rigid3d& true_cam_from_world, double tolerance,
                       int* count) const {
    int good = 0;
    *count = 0;
    for (size_t i = 0; i < frame.size(); ++i) {
      if (!frame.points[i].valid()) continue;
      const MapPoint* point = map.FindPoint(frame.points[i]);
      if (!point) continue;
      ++*count;
      const Eigen::Vector2d pixel = k().Project(true_cam_from_world * point->position);
      good += (pixel - frame.undistorted[i]).norm() < tolerance;
    }
    return *count ? static_cast<double>(good) / *count : 0;
  }

 private:
  std::unique_ptr<SyntheticSequence> sequence_;
  ViewGeometry geometry_;
  OrbExtractor extractor_{OrbOptions{}};
};

// The default strip, rendered views of it shared by the tests of one program.
inline RenderedViews& SharedStrip() {
  static RenderedViews* views = new RenderedViews();
  return *views;
}

// Distance between two poses: translation (same units) and rotation (degrees).
inline double TranslationError(const Rigid3d& a, const Rigid3d& b) {
  return (a.CentreInWorld() - b.CentreInWorld()).norm();
}
inline double RotationErrorDeg(const Rigid3d& a, const Rigid3d& b) {
  return a.rotation.angularDistance(b.rotation) * 180.0 / M_PI;
}

}  // namespace stitch::testing
