// Matching on rendered frames of the synthetic flight, where depth and poses are exact.

#include "stitch/map/matcher.h"

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "stitch/features/vocabulary.h"
#include "stitch/testing/rendered_views.h"

namespace stitch {
namespace {

testing::RenderedViews& Shared() {
  return testing::SharedStrip();
}

const Vocabulary& SharedVocabulary() {
  static const Vocabulary* v =
      new Vocabulary(Vocabulary::Load(std::string(STITCH_SOURCE_DIR) + "/vocabulary/default.stitchvoc"));
  return *v;
}

Frame RenderFrame(int index, cv::Mat* depth) {
  return Shared().Render(index, depth);
}
Map MapFromFrame(const Frame& frame, const cv::Mat& depth, Keyframe* out) {
  return Shared().MapFromFrame(frame, depth, out);
}
double Consistency(const Frame& frame, const Map& map, double tolerance, int* count) {
  return Shared().Consistency(frame, map, tolerance, count);
}

TEST(Matcher, ProjectionSearchFindsTheRightFeatures) {
  cv::Mat depth;
  const Frame reference = RenderFrame(40, &depth);
  Keyframe keyframe;
  const Map map = MapFromFrame(reference, depth, &keyframe);
  Frame current = RenderFrame(43, nullptr);
  std::vector<PointInView> in_view;
  for (const auto& [id, point] : map.points()) {
    PointInView view;
    if (PredictInView(point, *current.cam_from_world, Shared().k(), 0, 0, 639, 479, map.pyramid(), &view))
      in_view.push_back(view);
  }
  const int matched = SearchByProjection(&current, in_view, map, 1.0);
  int count = 0;
  EXPECT_GT(matched, 300);
  EXPECT_GT(Consistency(current, map, 3.0, &count), 0.95);
}

TEST(Matcher, MotionModelSearchFollowsTheLastFrame) {
  cv::Mat depth;
  Frame last = RenderFrame(60, &depth);
  Keyframe keyframe;
  const Map map = MapFromFrame(last, depth, &keyframe);
  last.points = keyframe.points;
  Frame current = RenderFrame(61, nullptr);
  const int matched = SearchByProjection(&current, last, map, Shared().k(), 15.0);
  int count = 0;
  // No ratio test here (as in ORB-SLAM): pose optimization sorts out the wrong ones.
  EXPECT_GT(matched, 300);
  EXPECT_GT(Consistency(current, map, 3.0, &count), 0.85);
}

TEST(Matcher, BowSearchMatchesAKeyframeToAFrame) {
  cv::Mat depth;
  Frame reference = RenderFrame(80, &depth);
  reference.bow = SharedVocabulary().Transform(reference.descriptors, &reference.bow_features, 2);
  Keyframe keyframe;
  const Map map = MapFromFrame(reference, depth, &keyframe);
  Frame current = RenderFrame(85, nullptr);
  current.bow = SharedVocabulary().Transform(current.descriptors, &current.bow_features, 2);
  const int matched = SearchByBow(keyframe, &current, map);
  int count = 0;
  EXPECT_GT(matched, 100);
  EXPECT_GT(Consistency(current, map, 3.0, &count), 0.95);
}

TEST(Matcher, IndexSearchFindsAtLeastWhatTheBowSearchFinds) {
  // The reference keyframe 8 frames (about 9 m) behind: brute force compares every pair, also
  // those the vocabulary's direct index never puts side by side; LSH nearly all of them.
  cv::Mat depth;
  Frame reference = RenderFrame(77, &depth);
  reference.bow = SharedVocabulary().Transform(reference.descriptors, &reference.bow_features, 2);
  Keyframe keyframe;
  const Map map = MapFromFrame(reference, depth, &keyframe);
  int matched[3] = {0, 0, 0};
  for (int method = 0; method < 3; ++method) {
    Frame current = RenderFrame(85, nullptr);
    if (method == 0) {
      current.bow = SharedVocabulary().Transform(current.descriptors, &current.bow_features, 2);
      matched[method] = SearchByBow(keyframe, &current, map);
    } else {
      const DescriptorIndex index(current.descriptors,
                                  method == 1 ? DescriptorSearch::kBruteForce : DescriptorSearch::kLsh);
      matched[method] = SearchByIndex(keyframe, &current, map, index);
    }
    int count = 0;
    EXPECT_GT(Consistency(current, map, 3.0, &count), 0.95) << "method " << method;
    EXPECT_EQ(count, matched[method]);
  }
  EXPECT_GT(matched[0], 150);  // measured: bow 234, brute force 360, LSH 361
  EXPECT_GE(matched[1], 1.3 * matched[0]);
  EXPECT_GE(matched[2], 0.9 * matched[1]);
}

TEST(Matcher, TriangulationSearchRespectsTheEpipolarGeometry) {
  cv::Mat depth1;
  Frame f1 = RenderFrame(100, &depth1);
  Frame f2 = RenderFrame(106, nullptr);
  for (Frame* f : {&f1, &f2}) f->bow = SharedVocabulary().Transform(f->descriptors, &f->bow_features, 2);
  Map map(MakeSubmapId(0, 1), ScalePyramid::From(OrbOptions()));
  Keyframe kf1 = KeyframeFromFrame(f1, MakeKeyframeId(map.id(), 0));
  Keyframe kf2 = KeyframeFromFrame(f2, MakeKeyframeId(map.id(), 1));
  const Eigen::Matrix3d f21 = FundamentalMatrix(kf1.cam_from_world, kf2.cam_from_world, Shared().k());
  const auto pairs = SearchForTriangulation(kf1, kf2, f21, Shared().k(), map.pyramid());
  EXPECT_GT(pairs.size(), 150u);
  // True correspondences: feature 1 back-projected with its true depth lands on feature 2.
  int right = 0;
  for (const auto& [i, j] : pairs) {
    const float z = depth1.at<float>(cvRound(kf1.keypoints[i].pt.y), cvRound(kf1.keypoints[i].pt.x));
    const Eigen::Vector2d n = Shared().k().Normalize(kf1.undistorted[i]);
    const Eigen::Vector3d world = kf1.cam_from_world.Inverse() * Eigen::Vector3d(n.x() * z, n.y() * z, z);
    right += (Shared().k().Project(kf2.cam_from_world * world) - kf2.undistorted[j]).norm() < 3.0;
  }
  EXPECT_GT(static_cast<double>(right) / pairs.size(), 0.9);
}

// Frame 43's keyframe placed half a degree off its true pose (about 4 pixels at the image
// centre), as another submap's keyframe is before the adjustment: frame 40's points are fused
// into it.
TEST(Matcher, FusingAnotherSubmapsPointsSearchesTheWholeRadius) {
  cv::Mat depth;
  const Frame reference = RenderFrame(40, &depth);
  Keyframe keyframe;
  const Map map = MapFromFrame(reference, depth, &keyframe);
  const Frame current = RenderFrame(43, nullptr);
  Keyframe other = KeyframeFromFrame(current, MakeKeyframeId(MakeSubmapId(0, 2), 0));
  const Rigid3d truth = other.cam_from_world;
  const double offset = 4.0 / Shared().k().fx;  // radians
  other.cam_from_world =
      Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(offset, Eigen::Vector3d::UnitY())), Eigen::Vector3d::Zero()) * truth;
  std::vector<MapPointId> candidates;
  for (const auto& [id, point] : map.points()) candidates.push_back(id);

  // Fused observations in `other`, and those whose feature is where the point truly projects.
  const auto fuse = [&](FuseSearch search, int* right) {
    Map fused = map;
    fused.AddKeyframe(other);
    const int count = Fuse(&fused, other.id, candidates, Shared().k(), 4.0, search);
    *right = 0;
    for (const auto& [id, point] : fused.points()) {
      const auto seen = point.observations.find(other.id);
      if (seen == point.observations.end()) continue;
      *right += (Shared().k().Project(truth * point.position) - other.undistorted[seen->second]).norm() < 3.0;
    }
    return count;
  };
  int right_within_noise = 0, right_whole = 0;
  const int within_noise = fuse(FuseSearch::kWithinNoise, &right_within_noise);
  const int whole = fuse(FuseSearch::kWholeRadius, &right_whole);
  // Measured: 422 fused searching the whole radius, 387 of them right (92%); 186 within the
  // noise bound (88% right): the others are 4 pixels off, beyond it at the finer levels.
  EXPECT_GT(whole, 300);
  EXPECT_LT(within_noise, 0.6 * whole);
  EXPECT_GT(right_whole, 0.85 * whole);
  EXPECT_GT(right_whole, 2 * right_within_noise);
}

}  // namespace
}  // namespace stitch

namespace stitch {
namespace {

TEST(ImageSharpness, IsTheMeanAbsoluteLaplacianOfTheHalfSizeImage) {
  // The one-pass sum against OpenCV's Laplacian (ksize 1, reflected borders), odd sizes included.
  for (const cv::Size size : {cv::Size(752, 480), cv::Size(641, 479), cv::Size(5, 7), cv::Size(3, 3)}) {
    cv::Mat image(size, CV_8U);
    cv::randu(image, 0, 256);
    cv::Mat half, laplacian;
    cv::resize(image, half, cv::Size(), 0.5, 0.5, cv::INTER_AREA);
    cv::Laplacian(half, laplacian, CV_16S, 1);
    EXPECT_NEAR(ImageSharpness(image), cv::mean(cv::abs(laplacian))[0], 1e-9) << size;
  }
  // Blur lowers it.
  cv::Mat image(480, 640, CV_8U), blurred;
  cv::randu(image, 0, 256);
  cv::GaussianBlur(image, blurred, cv::Size(9, 9), 3);
  EXPECT_LT(ImageSharpness(blurred), 0.3 * ImageSharpness(image));
}

}  // namespace
}  // namespace stitch
