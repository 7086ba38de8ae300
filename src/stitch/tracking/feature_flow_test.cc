// Following map points by optical flow between keyframes (feature_flow.h), on rendered views of
// the default flight's strip with exact poses and depth; and the tracker using it.

#include <algorithm>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "stitch/testing/default_vocabulary.h"
#include "stitch/testing/rendered_views.h"
#include "stitch/tracking/feature_flow.h"
#include "stitch/tracking/frame_placer.h"
#include "stitch/tracking/tracking.h"

namespace stitch {
namespace {

using testing::RenderedViews;

// Frame `index` of the strip, extracted, as the flow's source: its features at known depth are
// the map's points.
struct Source {
  Map map{SubmapId(), ScalePyramid()};
  Frame frame;
  cv::Mat image;
  FeatureFlow flow{FeatureFlowOptions()};

  // `image` (of the strip's camera) followed from the source as frame `index`.
  Frame Follow(const cv::Mat& image, int index, const Rigid3d& predicted, int64_t t_ns = 0) const {
    RenderedViews& strip = testing::SharedStrip();
    return flow.Follow(image, index, t_ns, map, predicted, strip.sequence().camera(), strip.geometry().undistorter);
  }
};

Source MakeSource(int index) {
  RenderedViews& strip = testing::SharedStrip();
  Source source;
  cv::Mat depth;
  source.image = strip.sequence().RenderFrame(index, &depth);
  source.frame = strip.Render(index);
  Keyframe keyframe;
  source.map = strip.MapFromFrame(source.frame, depth, &keyframe);
  source.frame.points = keyframe.points;
  source.frame.outlier.assign(source.frame.size(), 0);
  source.flow.KeepSource(source.image, source.frame);
  return source;
}

// `truth` cam_from_world moved 0.5 m and turned 0.2 degrees: what a motion model predicts.
Rigid3d Predicted(const Rigid3d& truth) {
  Rigid3d world_from_cam = truth.Inverse();
  world_from_cam.translation += Eigen::Vector3d(0.3, -0.3, 0.2);
  world_from_cam.rotation =
      world_from_cam.rotation * Eigen::Quaterniond(Eigen::AngleAxisd(0.2 * M_PI / 180, Eigen::Vector3d::UnitX()));
  return world_from_cam.Inverse();
}

TEST(FeatureFlow, FollowsTheMapPointsToWhereTheNextViewSeesThem) {
  RenderedViews& strip = testing::SharedStrip();
  Source source = MakeSource(0);
  FeatureFlow& flow = source.flow;
  EXPECT_EQ(flow.source_frame_index(), 0);
  EXPECT_GT(flow.source_points(), 300);
  // Two frames on (2.3 m, about 15 pixels of motion).
  const Rigid3d truth = strip.WorldFromCam(2).Inverse();
  const Frame followed = source.Follow(strip.sequence().RenderFrame(2), 2, Predicted(truth), 7);
  EXPECT_EQ(followed.frame_index, 2);
  EXPECT_EQ(followed.t_ns, 7);
  EXPECT_EQ(followed.descriptors.rows, 0) << "a followed frame has no descriptors";
  ASSERT_GT(followed.size(), 0.9 * flow.source_points()) << "most points stay in view and are followed";
  ASSERT_EQ(followed.points.size(), followed.size());
  ASSERT_EQ(followed.undistorted.size(), followed.size());
  // Each followed position against where the true pose projects its point.
  std::vector<double> errors;
  for (size_t i = 0; i < followed.size(); ++i) {
    const MapPoint* point = source.map.FindPoint(followed.points[i]);
    ASSERT_NE(point, nullptr);
    const std::optional<Eigen::Vector2d> seen = strip.sequence().camera().Project(truth * point->position);
    ASSERT_TRUE(seen);
    const cv::Point2f& at = followed.keypoints[i].pt;
    errors.push_back((*seen - Eigen::Vector2d(at.x, at.y)).norm());
  }
  std::sort(errors.begin(), errors.end());
  // The source's keypoints lie within a pixel or so of their points' projections (their level's
  // grid, depth read at the rounded pixel); the flow adds little to that.
  EXPECT_LT(errors[errors.size() / 2], 0.8) << "median pixels from the true projection";
  EXPECT_LT(errors[errors.size() * 9 / 10], 2.0) << "90th percentile";
}

TEST(FeatureFlow, AFollowedFramesPoseComesOutNearTheTruth) {
  RenderedViews& strip = testing::SharedStrip();
  Source source = MakeSource(0);
  FeatureFlow& flow = source.flow;
  const Rigid3d truth = strip.WorldFromCam(3).Inverse();
  Frame followed = source.Follow(strip.sequence().RenderFrame(3), 3, Predicted(truth));
  FramePlacer placer(TrackingOptions(), &strip.geometry(), &testing::DefaultVocabulary());
  const int inliers = placer.OptimizeFramePose(source.map, &followed, /*discard_outliers=*/true);
  EXPECT_GT(inliers, 0.8 * flow.source_points());
  ASSERT_TRUE(followed.cam_from_world);
  // At 70 m above the ground a pixel is 0.16 m.
  EXPECT_LT(testing::TranslationError(*followed.cam_from_world, truth), 0.2);
  EXPECT_LT(testing::RotationErrorDeg(*followed.cam_from_world, truth), 0.1);
}

TEST(FeatureFlow, NothingIsFollowedIntoAnImageThatDoesNotShowIt) {
  RenderedViews& strip = testing::SharedStrip();
  Source source = MakeSource(0);
  FeatureFlow& flow = source.flow;
  const Rigid3d truth = strip.WorldFromCam(2).Inverse();
  // A grey image (a lens cap, a dead sensor) and another place altogether (frame 150: 170 m on).
  const cv::Mat grey(source.image.size(), CV_8UC1, cv::Scalar(128));
  const Frame into_grey = source.Follow(grey, 2, truth);
  // A few low-contrast patches stay within the flow's error of grey; the tracker keeps a followed
  // frame only with most of its reference keyframe's points (flow.keyframe_margin).
  EXPECT_LT(into_grey.size(), 0.1 * flow.source_points());
  Frame elsewhere = source.Follow(strip.sequence().RenderFrame(150), 2, truth);
  FramePlacer placer(TrackingOptions(), &strip.geometry(), &testing::DefaultVocabulary());
  EXPECT_LT(placer.OptimizeFramePose(source.map, &elsewhere, true), TrackingOptions().min_inliers)
      << "what flow finds in another place does not agree on a pose";
  flow.Clear();
  EXPECT_FALSE(flow.has_source());
  EXPECT_EQ(source.Follow(strip.sequence().RenderFrame(2), 2, truth).size(), 0u);
}

TEST(FeatureFlow, APointWhoseDepthChangesMuchIsNotFollowed) {
  RenderedViews& strip = testing::SharedStrip();
  Source source = MakeSource(0);
  const Rigid3d truth = strip.WorldFromCam(2).Inverse();
  const cv::Mat image = strip.sequence().RenderFrame(2);
  // The prediction moved along the optical axis towards the ground (70 m below): its points'
  // depths change by that share, and their patches by its inverse.
  const auto towards_ground = [&](double metres) {
    Rigid3d world_from_cam = truth.Inverse();
    world_from_cam.translation += world_from_cam.rotation * Eigen::Vector3d(0, 0, metres);
    return world_from_cam.Inverse();
  };
  EXPECT_GT(source.Follow(image, 2, towards_ground(1.4)).size(), 0.9 * source.flow.source_points())
      << "2%: within max_scale_change (5%)";
  EXPECT_EQ(source.Follow(image, 2, towards_ground(7.0)).size(), 0u) << "10%: beyond it";
  FeatureFlowOptions no_limit;
  no_limit.max_scale_change = 0;
  Source unlimited = MakeSource(0);
  unlimited.flow = FeatureFlow(no_limit);
  unlimited.flow.KeepSource(unlimited.image, unlimited.frame);
  EXPECT_GT(unlimited.Follow(image, 2, towards_ground(7.0)).size(), 0u) << "0: no limit";
}

// The tracker on the strip's first 15 frames (without a mapper's points it loses the strip
// after): which frames flow placed, and which were keyframes.
struct StripRun {
  int followed = 0;
  int followed_keyframes = 0;
  int tracked = 0;
};

StripRun TrackStrip(const TrackingOptions& options) {
  RenderedViews& strip = testing::SharedStrip();
  Tracking tracking(options, strip.sequence().camera(), &testing::DefaultVocabulary(), 20);
  StripRun run;
  for (int i = 0; i < 15; ++i) {
    const Tracking::Output output =
        tracking.Track(strip.sequence().RenderFrame(i), i, strip.sequence().flight().TimestampNs(i));
    if (output.result.state != TrackingState::kOk) continue;
    ++run.tracked;
    if (std::string(output.result.tracked_by) == "optical flow") {
      ++run.followed;
      run.followed_keyframes += output.result.is_keyframe || !output.new_keyframes.empty();
      EXPECT_GE(output.result.num_tracked_points, options.min_inliers);
    }
  }
  return run;
}

TEST(FeatureFlow, TheTrackerFollowsFramesBetweenKeyframesAndExtractsTheRest) {
  TrackingOptions options;
  options.flow.enabled = true;
  options.keyframes_in_flight = 8;  // no mapper here to answer
  const StripRun followed = TrackStrip(options);
  EXPECT_GE(followed.followed, 3);
  EXPECT_EQ(followed.followed_keyframes, 0) << "a followed frame has no descriptors to make a keyframe of";
  EXPECT_GE(followed.tracked, 12);
  options.flow.enabled = false;
  const StripRun extracted = TrackStrip(options);
  EXPECT_EQ(extracted.followed, 0);
  EXPECT_GE(extracted.tracked, 12);
  // A camera turning faster than flow.max_turn_deg a frame is extracted.
  options.flow.enabled = true;
  options.flow.max_turn_deg = 0;
  EXPECT_EQ(TrackStrip(options).followed, 0);
}

}  // namespace
}  // namespace stitch
