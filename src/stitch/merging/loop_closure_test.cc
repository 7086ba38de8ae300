// In-map loop closure: a submap whose path comes back over its start, where the tracker did not
// recognize the old points (so the two ends are not covisible) and drifted on the way.

#include <cstdio>

#include <gtest/gtest.h>

#include "stitch/merging/merger.h"
#include "stitch/testing/default_vocabulary.h"
#include "stitch/testing/submap_updates.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

const Camera kCamera = Camera::Pinhole(640, 480, 450, 450, 319.5, 239.5);
const SubmapId kSubmap = MakeSubmapId(0, 1);
constexpr int kKeyframes = 30;
constexpr int kRecognizedWithin = 10;  // the tracker re-uses a point seen this many keyframes ago, no older

// Keyframes on a circle of 6 m radius at 10 m height, looking down at rough ground.
Rigid3d TrueWorldFromCam(int k) {
  const double angle = 2 * M_PI * k / kKeyframes;
  const Eigen::Quaterniond down(Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()));
  return Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitZ())) * down,
                 Eigen::Vector3d(6 * std::cos(angle), 6 * std::sin(angle), 10));
}

// The tracker's drift by keyframe k: growing steadily to 3% in scale, 2.3 degrees and 0.5 m.
Sim3d SubmapFromWorld(int k) {
  const double t = static_cast<double>(k) / (kKeyframes - 1);
  return Sim3d(1 + 0.03 * t, Eigen::Quaterniond(Eigen::AngleAxisd(0.04 * t, Eigen::Vector3d(0.3, 0.2, 1).normalized())),
               t * Eigen::Vector3d(0.4, -0.3, 0.1));
}

std::vector<SubmapUpdate> LoopingSubmap() {
  Rng rng(5);
  const ScalePyramid pyramid = ScalePyramid::From(OrbOptions());
  Map map(kSubmap, pyramid);
  std::vector<Eigen::Vector3d> ground;
  std::vector<cv::Mat> descriptors;
  for (int p = 0; p < 2500; ++p) {
    const double r = 14 * std::sqrt(rng.Uniform()), a = rng.Uniform(0, 2 * M_PI);
    ground.emplace_back(r * std::cos(a), r * std::sin(a), rng.Uniform(-0.5, 0.5));
    cv::Mat d(1, 32, CV_8U);
    for (int b = 0; b < 32; ++b) d.at<uint8_t>(0, b) = static_cast<uint8_t>(rng.UniformInt(0, 255));
    descriptors.push_back(d);
  }
  std::vector<std::vector<std::pair<int, MapPointId>>> map_points(ground.size());  // (creating keyframe, id)
  uint32_t next_point = 0;
  for (int k = 0; k < kKeyframes; ++k) {
    const Rigid3d cam_from_world = TrueWorldFromCam(k).Inverse();
    const Sim3d submap_from_cam =
        SubmapFromWorld(k) * Sim3d(1, TrueWorldFromCam(k).rotation, TrueWorldFromCam(k).translation);
    Keyframe keyframe;
    keyframe.id = MakeKeyframeId(kSubmap, k);
    keyframe.frame_index = 10 * k;
    keyframe.t_ns = 500'000'000LL * k;
    keyframe.cam_from_world = Rigid3d(submap_from_cam.rotation, submap_from_cam.translation).Inverse();
    std::vector<int> seen;
    for (size_t p = 0; p < ground.size(); ++p) {
      const Eigen::Vector3d in_cam = cam_from_world * ground[p];
      const Eigen::Vector2d pixel = kCamera.Intrinsics().Project(in_cam);
      if (in_cam.z() > 0 && pixel.x() > 5 && pixel.x() < 634 && pixel.y() > 5 && pixel.y() < 474)
        seen.push_back(static_cast<int>(p));
    }
    keyframe.descriptors = cv::Mat(static_cast<int>(seen.size()), 32, CV_8U);
    for (size_t i = 0; i < seen.size(); ++i) {
      const int p = seen[i];
      const Eigen::Vector2d pixel = kCamera.Intrinsics().Project(cam_from_world * ground[p]);
      cv::KeyPoint keypoint(static_cast<float>(pixel.x()), static_cast<float>(pixel.y()), 31, 0);
      keypoint.octave = 0;
      keyframe.keypoints.push_back(keypoint);
      descriptors[p].copyTo(keyframe.descriptors.row(static_cast<int>(i)));
      MapPointId id;
      for (const auto& [creator, existing] : map_points[p]) {
        if (k - creator <= kRecognizedWithin) id = existing;
      }
      if (!id.valid()) {
        id = MakeMapPointId(kSubmap, next_point++);
        map_points[p].push_back({k, id});
        MapPoint point;
        point.id = id;
        point.position = SubmapFromWorld(k) * ground[p];
        descriptors[p].row(0).copyTo(cv::Mat(1, 32, CV_8U, point.descriptor.data()));
        map.AddPoint(point);
      }
      keyframe.points.push_back(id);
    }
    map.AddKeyframe(keyframe);
  }
  for (const auto& [id, point] : map.points()) map.UpdatePointGeometry(id);
  return testing::KeyframeByKeyframeUpdates(&map, kCamera);
}

// The worst keyframe position error against the truth, in the frame of keyframe 0 (which the
// merger holds fixed and which has no drift).
double WorstError(const std::map<KeyframeId, Sim3d>& world_from_cam) {
  double worst = 0;
  for (const auto& [id, pose] : world_from_cam) {
    worst = std::max(worst, (pose.translation - TrueWorldFromCam(static_cast<int>(IndexOf(id))).translation).norm());
  }
  return worst;
}

TEST(LoopClosure, TheMergerClosesALoopWithinASubmapAndTakesOutMostOfTheDrift) {
  Merger merger(MergerOptions(), &testing::DefaultVocabulary(), ScalePyramid::From(OrbOptions()));
  for (const SubmapUpdate& update : LoopingSubmap()) merger.Apply(update);

  ASSERT_GE(merger.loops().size(), 2u);
  for (const ConnectedFrame& loop : merger.loops()) {
    const int a = static_cast<int>(IndexOf(loop.keyframe_a)), b = static_cast<int>(IndexOf(loop.keyframe_b));
    EXPECT_GE(a, kKeyframes / 2);  // a late keyframe...
    EXPECT_LT(b, 8);               // ...seeing the start again
    // Each measures the drift between its ends (to the drift's change over the few keyframes
    // that created the points it matched).
    const Sim3d error = loop.b_from_a * SubmapFromWorld(a) * SubmapFromWorld(b).Inverse();
    EXPECT_LT(RotationAngle(error.rotation), 1.0 * M_PI / 180);
    EXPECT_NEAR(error.scale, 1.0, 0.01);
  }
  EXPECT_TRUE(merger.connections().empty());  // nothing between submaps: there is one

  std::map<KeyframeId, Sim3d> drifted;
  for (const auto& [id, keyframe] : merger.submaps().at(kSubmap).map.keyframes()) {
    const Rigid3d submap_from_cam = keyframe.cam_from_world.Inverse();
    drifted[id] = Sim3d(1, submap_from_cam.rotation, submap_from_cam.translation);
  }
  const Merger::Graph graph = merger.Solve(/*refine=*/true);
  EXPECT_GE(graph.loops_used, 2);
  EXPECT_EQ(graph.tree.size(), 0u);
  const double before = WorstError(drifted), after = WorstError(graph.keyframe_poses);
  std::printf("worst keyframe error %.3f m drifted, %.3f m after the loops (%d used)\n", before, after,
              graph.loops_used);
  EXPECT_GT(before, 0.5);
  EXPECT_LT(after, 0.3 * before) << "before " << before << " m, after " << after << " m";
}

}  // namespace
}  // namespace stitch
