#include "stitch/tracking/rolling_shutter.h"

#include <gtest/gtest.h>

#include "stitch/util/rng.h"

namespace stitch {
namespace {

const Camera kCamera = Camera::Pinhole(640, 480, 450, 450, 319.5, 239.5);

// Points in the camera at the first row's time; `motion` moves points in the camera per second.
// Each is seen where it is when its row is read out (its row found by fixed-point iteration).
struct RollingShutterCase {
  Frame frame;
  std::vector<Eigen::Vector2d> global;  // where a global shutter at the first row's time sees each
};

RollingShutterCase Observe(const std::vector<Eigen::Vector3d>& points, const Eigen::Vector3d& w,
                           const Eigen::Vector3d& v, double line_delay_s, const Undistorter& undistorter) {
  RollingShutterCase c;
  for (const Eigen::Vector3d& p : points) {
    const Eigen::Vector2d global = *kCamera.Project(p);
    Eigen::Vector2d seen = global;
    for (int it = 0; it < 5; ++it) {
      const double t = seen.y() * line_delay_s;
      const Eigen::Vector3d moved = Eigen::AngleAxisd(t * w.norm(), w.normalized()) * p + t * v;
      seen = *kCamera.Project(moved);
    }
    if (seen.x() < 0 || seen.y() < 0 || seen.x() > 639 || seen.y() > 479) continue;
    cv::KeyPoint keypoint;  // in 1/8 pixel, as MakeFrame rounds them
    keypoint.pt =
        cv::Point2f(static_cast<float>(std::round(seen.x() * 8) / 8), static_cast<float>(std::round(seen.y() * 8) / 8));
    c.frame.keypoints.push_back(keypoint);
    c.frame.undistorted.push_back(undistorter.Undistort(keypoint.pt.x, keypoint.pt.y));
    c.global.push_back(global);
  }
  c.frame.grid = FeatureGrid(c.frame.undistorted, undistorter);
  return c;
}

// The motion per second as the tracker's velocity over `interval` seconds.
Rigid3d Velocity(const Eigen::Vector3d& w, const Eigen::Vector3d& v, double interval) {
  return Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(interval * w.norm(), w.normalized())), interval * v);
}

// The farthest a feature is from where a global shutter saw it, pixels.
double WorstError(const RollingShutterCase& c) {
  double worst = 0;
  for (size_t i = 0; i < c.global.size(); ++i) {
    worst =
        std::max(worst, (Eigen::Vector2d(c.frame.keypoints[i].pt.x, c.frame.keypoints[i].pt.y) - c.global[i]).norm());
  }
  return worst;
}

// A camera panning at 30 degrees a second, read out over 19 ms: rows skew by up to 6 pixels;
// unrolled, every feature is where a global shutter saw it (depth plays no part in a rotation).
TEST(RollingShutter, UnrollsATurningCamerasFeaturesAtAnyDepth) {
  const Undistorter undistorter(kCamera);
  Rng rng(3);
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < 300; ++i) {
    const double z = rng.Uniform(2, 50);
    points.emplace_back(rng.Uniform(-0.7, 0.7) * z, rng.Uniform(-0.5, 0.5) * z, z);
  }
  const Eigen::Vector3d w(0.1, 30 * M_PI / 180, 0.05), v = Eigen::Vector3d::Zero();
  const double line_delay_s = 40e-6;
  RollingShutterCase c = Observe(points, w, v, line_delay_s, undistorter);
  ASSERT_GT(c.global.size(), 200u);
  EXPECT_GT(WorstError(c), 5.0);
  const double largest = UnrollRollingShutter(&c.frame, Velocity(w, v, 0.05), 0.05, line_delay_s,
                                              InverseDepthPlane::Constant(10.0), undistorter);
  EXPECT_GT(largest, 5.0);
  EXPECT_LT(WorstError(c), 0.3);
  // The frame's undistorted positions and grid follow its keypoints.
  for (size_t i = 0; i < c.global.size(); ++i) {
    EXPECT_NEAR(c.frame.undistorted[i].x(), c.frame.keypoints[i].pt.x, 1e-3);
    const std::vector<int> near =
        c.frame.grid.InArea(c.global[i].x(), c.global[i].y(), 1.0, c.frame.keypoints, c.frame.undistorted);
    EXPECT_NE(std::find(near.begin(), near.end(), static_cast<int>(i)), near.end()) << i;
  }
}

// A camera flying over flat ground at 20 m/s, 70 m up: the translation's skew is unrolled at the
// ground's depth.
TEST(RollingShutter, UnrollsAFlyingCamerasFeaturesAtTheGroundsDepth) {
  const Undistorter undistorter(kCamera);
  Rng rng(4);
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < 300; ++i) points.emplace_back(rng.Uniform(-50, 50), rng.Uniform(-37, 37), 70.0);
  const Eigen::Vector3d w = Eigen::Vector3d(0, 0, 1e-9), v(-20, 0, 0);
  const double line_delay_s = 40e-6;
  RollingShutterCase c = Observe(points, w, v, line_delay_s, undistorter);
  ASSERT_GT(c.global.size(), 200u);
  EXPECT_GT(WorstError(c), 2.0);
  UnrollRollingShutter(&c.frame, Velocity(w, v, 0.05), 0.05, line_delay_s, InverseDepthPlane::Constant(70.0),
                       undistorter);
  EXPECT_LT(WorstError(c), 0.2);
}

// A car's camera 1.5 m above a flat road, looking ahead at 15 m/s: the near rows (read last)
// move most. The road's inverse-depth plane (1/z = y / 1.5) unrolls every feature; one depth for
// all (the median's) cannot.
TEST(RollingShutter, UnrollsAForwardCamerasFeaturesByTheGroundsInverseDepthPlane) {
  const Undistorter undistorter(kCamera);
  Rng rng(5);
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < 400; ++i) points.emplace_back(rng.Uniform(-8, 8), 1.5, rng.Uniform(4, 60));
  const Eigen::Vector3d w = Eigen::Vector3d(0, 0, 1e-9), v(0, 0, -15);
  const double line_delay_s = 40e-6;
  const InverseDepthPlane road{0, 1 / 1.5, 0, 0, 1 / 4.0};
  RollingShutterCase c = Observe(points, w, v, line_delay_s, undistorter);
  ASSERT_GT(c.global.size(), 200u);
  RollingShutterCase one_depth = c;
  EXPECT_GT(WorstError(c), 2.0);
  UnrollRollingShutter(&c.frame, Velocity(w, v, 0.1), 0.1, line_delay_s, road, undistorter);
  EXPECT_LT(WorstError(c), 0.3);
  UnrollRollingShutter(&one_depth.frame, Velocity(w, v, 0.1), 0.1, line_delay_s, InverseDepthPlane::Constant(15),
                       undistorter);
  EXPECT_GT(WorstError(one_depth), 1.0);
}

// The plane comes from the last frame's tracked points: a camera pitched 60 degrees over flat
// ground, with a quarter of the points on roofs 15 m up, gives the ground's plane.
TEST(RollingShutter, TheInverseDepthPlaneIsTheGroundsUnderTheTrackedPoints) {
  Map map(MakeSubmapId(0, 1), ScalePyramid::From(OrbOptions()));
  Frame frame;
  const double pitch = 60 * M_PI / 180;
  // Camera at 20 m, pitched up from straight down by `pitch`: in the camera, the ground is
  // n . P = 20 with n the world's down direction.
  const Eigen::Vector3d down(0, std::sin(pitch), std::cos(pitch));
  frame.cam_from_world = Rigid3d();
  Rng rng(6);
  for (int i = 0; i < 200; ++i) {
    const Eigen::Vector3d ray(rng.Uniform(-0.6, 0.6), rng.Uniform(-0.1, 0.45), 1.0);
    const double height = i % 4 == 0 ? 5.0 : 20.0;  // a roof 15 m up, or the ground
    MapPoint point;
    point.id = map.NewPointId();
    point.position = ray * (height / down.dot(ray));
    map.AddPoint(point);
    frame.points.push_back(point.id);
    frame.outlier.push_back(0);
  }
  const InverseDepthPlane plane = FitInverseDepthPlane(map, frame);
  ASSERT_TRUE(plane.valid());
  for (const Eigen::Vector2d& xy : {Eigen::Vector2d(0, 0), Eigen::Vector2d(0.5, 0.4), Eigen::Vector2d(-0.5, 0.1)}) {
    const double truth = down.dot(Eigen::Vector3d(xy.x(), xy.y(), 1)) / 20.0;
    EXPECT_NEAR(plane.At(xy.x(), xy.y()), truth, 0.1 * truth) << xy.transpose();
  }
  EXPECT_FALSE(FitInverseDepthPlane(map, Frame()).valid()) << "an unposed frame";
}

TEST(RollingShutter, AGlobalShutterOrNoMotionLeavesTheFrameAsItIs) {
  const Undistorter undistorter(kCamera);
  RollingShutterCase c = Observe({Eigen::Vector3d(1, 1, 10), Eigen::Vector3d(-2, 1, 12)}, Eigen::Vector3d(0, 0.5, 0),
                                 Eigen::Vector3d::Zero(), 0, undistorter);
  const Frame before = c.frame;
  EXPECT_EQ(UnrollRollingShutter(&c.frame, Velocity(Eigen::Vector3d(0, 0.5, 0), Eigen::Vector3d::Zero(), 0.05), 0.05, 0,
                                 InverseDepthPlane::Constant(10), undistorter),
            0.0);
  EXPECT_EQ(UnrollRollingShutter(&c.frame, Rigid3d(), 0.05, 40e-6, InverseDepthPlane::Constant(10), undistorter), 0.0);
  EXPECT_EQ(c.frame.keypoints[1].pt, before.keypoints[1].pt);
}

}  // namespace
}  // namespace stitch
