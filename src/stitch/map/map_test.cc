#include "stitch/map/map.h"

#include <gtest/gtest.h>
#include <thread>

namespace stitch {
namespace {

// A keyframe with `n` features (no image), observing the given points through features 0...
Keyframe MakeKeyframe(const Map& map, uint32_t index, const std::vector<MapPointId>& observed, int n = 50) {
  Keyframe keyframe;
  keyframe.id = MakeKeyframeId(map.id(), index);
  keyframe.cam_from_world = Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(-0.1 * index, 0, 0));
  for (int i = 0; i < n; ++i) {
    cv::KeyPoint kp(10.0f + i, 20.0f, 31);
    kp.octave = i % 3;
    keyframe.keypoints.push_back(kp);
    keyframe.undistorted.emplace_back(10.0 + i, 20.0);
  }
  keyframe.descriptors = cv::Mat::zeros(n, 32, CV_8U);
  for (int i = 0; i < n; ++i) keyframe.descriptors.at<uint8_t>(i, 0) = static_cast<uint8_t>(i);
  keyframe.points.assign(n, MapPointId());
  for (size_t i = 0; i < observed.size(); ++i) keyframe.points[i] = observed[i];
  return keyframe;
}

struct Fixture {
  Map map{MakeSubmapId(2, 3), ScalePyramid::From(OrbOptions())};
  std::vector<MapPointId> points;
  Fixture() {
    for (int i = 0; i < 40; ++i) {
      MapPoint p;
      p.id = map.NewPointId();
      p.position = Eigen::Vector3d(0.1 * i, 0, 5);
      points.push_back(p.id);
      map.AddPoint(p);
    }
  }
};

TEST(Ids, PackAgentSubmapAndIndex) {
  const SubmapId submap = MakeSubmapId(5, 17);
  const KeyframeId kf = MakeKeyframeId(submap, 123456);
  EXPECT_EQ(AgentNumber(SubmapOf(kf)), 5);
  EXPECT_EQ(SubmapNumber(SubmapOf(kf)), 17);
  EXPECT_EQ(IndexOf(kf), 123456u);
  EXPECT_FALSE(KeyframeId().valid());
  EXPECT_NE(MakeKeyframeId(MakeSubmapId(5, 18), 1), MakeKeyframeId(MakeSubmapId(6, 17), 1));
}

TEST(Map, AKeyframeGivesBackTheFrameItWasMadeFrom) {
  const Map map(MakeSubmapId(0, 1), ScalePyramid::From(OrbOptions()));
  Keyframe keyframe = MakeKeyframe(map, 4, {MakeMapPointId(map.id(), 7), MapPointId(), MakeMapPointId(map.id(), 9)});
  keyframe.frame_index = 12;
  keyframe.t_ns = 34;
  const Frame frame = FrameFromKeyframe(keyframe);
  EXPECT_EQ(frame.frame_index, 12);
  EXPECT_EQ(frame.t_ns, 34);
  ASSERT_EQ(frame.size(), keyframe.keypoints.size());
  EXPECT_EQ(frame.points, keyframe.points);
  EXPECT_EQ(frame.outlier, std::vector<char>(frame.size(), 0));
  EXPECT_EQ(frame.CountTracked(), 2);
  ASSERT_TRUE(frame.cam_from_world);
  EXPECT_LT((frame.cam_from_world->translation - keyframe.cam_from_world.translation).norm(), 1e-12);
  EXPECT_EQ(cv::norm(frame.descriptors, keyframe.descriptors, cv::NORM_HAMMING), 0);
  // And back: the same keyframe.
  const Keyframe again = KeyframeFromFrame(frame, keyframe.id);
  EXPECT_EQ(again.points, keyframe.points);
  EXPECT_EQ(again.frame_index, 12);
}

TEST(Map, ObservationsAndCovisibilityFollowSharedPoints) {
  Fixture f;
  // Keyframe 0 sees points 0-29, keyframe 1 points 10-39 (20 shared), keyframe 2 points 25-34 (5 with kf0, 10 with
  // kf1). Inserted one after the other, as a mapper does.
  f.map.AddKeyframe(MakeKeyframe(f.map, 0, {f.points.begin(), f.points.begin() + 30}));
  f.map.UpdateConnections(MakeKeyframeId(f.map.id(), 0));
  f.map.AddKeyframe(MakeKeyframe(f.map, 1, {f.points.begin() + 10, f.points.begin() + 40}));
  f.map.UpdateConnections(MakeKeyframeId(f.map.id(), 1));
  f.map.AddKeyframe(MakeKeyframe(f.map, 2, {f.points.begin() + 25, f.points.begin() + 35}));
  f.map.UpdateConnections(MakeKeyframeId(f.map.id(), 2));
  const KeyframeId k0 = MakeKeyframeId(f.map.id(), 0), k1 = MakeKeyframeId(f.map.id(), 1),
                   k2 = MakeKeyframeId(f.map.id(), 2);
  EXPECT_EQ(f.map.FindPoint(f.points[12])->observations.size(), 2u);
  EXPECT_EQ(f.map.FindKeyframe(k0)->covisibility.at(k1), 20);
  EXPECT_EQ(f.map.FindKeyframe(k1)->covisibility.at(k2), 10);
  EXPECT_EQ(f.map.FindKeyframe(k0)->covisibility.at(k2), 5);
  // Ordered neighbours keep weights >= 15 (or the single best).
  EXPECT_EQ(f.map.BestCovisible(k0, 5), std::vector<KeyframeId>{k1});
  EXPECT_EQ(f.map.BestCovisible(k2, 5), std::vector<KeyframeId>{k1});
  EXPECT_EQ(f.map.FindKeyframe(k1)->parent, k0);
}

// A map read whole connects its keyframes in one pass, to what keyframe-by-keyframe updates in id
// order give: covisibility, its order, and the spanning tree.
TEST(Map, ConnectingAllAtOnceGivesWhatUpdatingEachGives) {
  Fixture one, all;
  const std::vector<std::vector<int>> seen = {{0, 10}, {5, 20}, {8, 30}, {0, 40}, {15, 25}, {2, 12}};
  for (Fixture* f : {&one, &all}) {
    for (size_t k = 0; k < seen.size(); ++k) {
      std::vector<MapPointId> observed(f->points.begin() + seen[k][0], f->points.begin() + seen[k][1]);
      f->map.AddKeyframe(MakeKeyframe(f->map, static_cast<uint32_t>(k), observed));
    }
  }
  for (size_t k = 0; k < seen.size(); ++k) one.map.UpdateConnections(MakeKeyframeId(one.map.id(), k));
  all.map.ConnectAll();
  for (size_t k = 0; k < seen.size(); ++k) {
    const KeyframeId id = MakeKeyframeId(one.map.id(), k);
    const Keyframe& a = *one.map.FindKeyframe(id);
    const Keyframe& b = *all.map.FindKeyframe(id);
    EXPECT_EQ(a.covisibility, b.covisibility) << k;
    EXPECT_EQ(a.ordered, b.ordered) << k;
    EXPECT_EQ(a.parent, b.parent) << k;
    EXPECT_EQ(a.children, b.children) << k;
    EXPECT_FALSE(b.covisibility.empty()) << k;
  }
}

TEST(Map, ErasingObservationsRemovesUnderObservedPoints) {
  Fixture f;
  f.map.AddKeyframe(MakeKeyframe(f.map, 0, {f.points[0], f.points[1]}));
  f.map.AddKeyframe(MakeKeyframe(f.map, 1, {f.points[0], f.points[1]}));
  const KeyframeId k0 = MakeKeyframeId(f.map.id(), 0);
  f.map.EraseObservation(k0, f.points[0]);
  EXPECT_EQ(f.map.FindPoint(f.points[0]), nullptr);  // one observation left: removed
  EXPECT_FALSE(f.map.FindKeyframe(MakeKeyframeId(f.map.id(), 1))->points[0].valid());
  EXPECT_NE(f.map.FindPoint(f.points[1]), nullptr);
}

TEST(Map, ReplacingAPointMovesItsObservations) {
  Fixture f;
  f.map.AddKeyframe(MakeKeyframe(f.map, 0, {f.points[0]}));
  f.map.AddKeyframe(MakeKeyframe(f.map, 1, {f.points[1]}));
  f.map.AddKeyframe(MakeKeyframe(f.map, 2, {f.points[1]}));
  f.map.ReplacePoint(f.points[0], f.points[1]);
  EXPECT_EQ(f.map.FindPoint(f.points[0]), nullptr);
  EXPECT_EQ(f.map.FindPoint(f.points[1])->observations.size(), 3u);
  EXPECT_EQ(f.map.FindKeyframe(MakeKeyframeId(f.map.id(), 0))->points[0], f.points[1]);
}

TEST(Map, RemovingAKeyframeReconnectsTheSpanningTree) {
  Fixture f;
  std::vector<MapPointId> all(f.points.begin(), f.points.begin() + 30);
  for (uint32_t k = 0; k < 3; ++k) {
    f.map.AddKeyframe(MakeKeyframe(f.map, k, all));
    f.map.UpdateConnections(MakeKeyframeId(f.map.id(), k));
  }
  const KeyframeId k0 = MakeKeyframeId(f.map.id(), 0), k1 = MakeKeyframeId(f.map.id(), 1),
                   k2 = MakeKeyframeId(f.map.id(), 2);
  ASSERT_EQ(f.map.FindKeyframe(k2)->parent, k0);
  f.map.RemoveKeyframe(k1);
  EXPECT_EQ(f.map.FindKeyframe(k1), nullptr);
  EXPECT_FALSE(f.map.FindKeyframe(k0)->covisibility.count(k1));
  EXPECT_EQ(f.map.FindPoint(f.points[3])->observations.size(), 2u);
}

TEST(Map, PointGeometryGivesDirectionAndScaleRange) {
  Fixture f;
  f.map.AddKeyframe(MakeKeyframe(f.map, 0, {f.points[0]}));
  f.map.AddKeyframe(MakeKeyframe(f.map, 1, {f.points[0]}));
  f.map.UpdatePointGeometry(f.points[0]);
  const MapPoint* p = f.map.FindPoint(f.points[0]);
  EXPECT_NEAR(p->normal.norm(), 1.0, 1e-12);
  EXPECT_GT(p->normal.z(), 0.99);  // the cameras look at it along +z
  EXPECT_GT(p->max_distance, 4.9f);
  EXPECT_NEAR(p->max_distance / p->min_distance, std::pow(1.2, 7), 1e-3);
}

TEST(Undistorter, FollowsTheExactInverseOfAStrongDistortionBetweenItsPixels) {
  // The TUM fr1 camera's distortion (k1 0.26, k2 -0.95, k3 1.16): tens of pixels at the corners.
  const Camera camera =
      Camera::Pinhole(640, 480, 517.306, 516.469, 318.643, 255.314, 0.262383, -0.953104, -0.005358, 0.002628, 1.16331);
  const Undistorter undistorter(camera);
  double worst = 0;
  for (double y = 0; y <= 479; y += 3.7) {
    for (double x = 0; x <= 639; x += 2.9) {
      worst = std::max(worst, (undistorter.Undistort(x, y) - camera.UndistortPixel({x, y})).norm());
    }
  }
  worst = std::max(worst, (undistorter.Undistort(639, 479) - camera.UndistortPixel({639, 479})).norm());
  EXPECT_LT(worst, 0.01);
  // Outside the image: the exact inverse.
  EXPECT_LT((undistorter.Undistort(-3, 500) - camera.UndistortPixel({-3, 500})).norm(), 1e-9);
  // The bounds enclose every border pixel's undistorted position.
  const Eigen::Vector2d corner = camera.UndistortPixel({0, 0});
  EXPECT_LE(undistorter.min_x(), corner.x());
  EXPECT_LE(undistorter.min_y(), corner.y());
}

TEST(Undistorter, FillsItsTableOnlyWhereKeypointsLieAndSharesItWithItsCopies) {
  const Camera camera =
      Camera::Pinhole(640, 480, 517.306, 516.469, 318.643, 255.314, 0.262383, -0.953104, -0.005358, 0.002628, 1.16331);
  const Undistorter undistorter(camera);
  EXPECT_EQ(undistorter.pixels_filled(), 0);  // no whole table at construction
  const Undistorter copy = undistorter;
  const Eigen::Vector2d first = copy.Undistort(100.25, 200.5);
  EXPECT_EQ(undistorter.pixels_filled(), 4);  // the four pixels around the point, in the shared table
  EXPECT_EQ(undistorter.Undistort(100.25, 200.5), first);
  // Threads filling the same pixels at once answer as one thread alone does.
  const Undistorter shared(camera), alone(camera);
  std::vector<Eigen::Vector2d> answers[2];
  std::vector<std::thread> threads;
  for (auto& answer : answers) {
    threads.emplace_back([&shared, &answer] {
      for (double y = 10; y < 470; y += 7.3) answer.push_back(shared.Undistort(320.6, y));
    });
  }
  for (auto& t : threads) t.join();
  size_t k = 0;
  for (double y = 10; y < 470; y += 7.3, ++k) {
    EXPECT_EQ(answers[0][k], alone.Undistort(320.6, y));
    EXPECT_EQ(answers[1][k], answers[0][k]);
  }
}

TEST(Undistorter, LeavesAPinholeCameraAsItIs) {
  const Undistorter undistorter(Camera::Pinhole(3840, 2160, 2700, 2700, 1919.5, 1079.5));
  EXPECT_EQ(undistorter.Undistort(1234.25, 567.75), Eigen::Vector2d(1234.25, 567.75));
  EXPECT_EQ(undistorter.min_x(), 0);
  EXPECT_EQ(undistorter.max_x(), 3839);
  EXPECT_EQ(undistorter.max_y(), 2159);
}

}  // namespace
}  // namespace stitch
