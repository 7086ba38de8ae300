#include "stitch/geometry/camera.h"

#include <gtest/gtest.h>

#include "stitch/util/error.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

// EuRoC cam0 (radial-tangential) and a typical fisheye.
Camera EurocCamera() {
  return Camera::Pinhole(752, 480, 458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359,
                         1.76187114e-05);
}
Camera FisheyeCamera() {
  return Camera(CameraModel::kFisheye, 640, 480, {380, 380, 320, 240, -0.01, 0.05, -0.08, 0.03});
}

TEST(Camera, PinholeProjectsByFocalAndCentre) {
  const Camera camera = Camera::Pinhole(640, 480, 500, 400, 320, 240);
  const auto pixel = camera.Project(Eigen::Vector3d(1, -2, 10));
  ASSERT_TRUE(pixel);
  EXPECT_NEAR(pixel->x(), 320 + 50, 1e-12);
  EXPECT_NEAR(pixel->y(), 240 - 80, 1e-12);
  EXPECT_FALSE(camera.Project(Eigen::Vector3d(0, 0, -1)));
}

TEST(Camera, UndistortionInvertsDistortionOverTheImage) {
  for (const Camera& camera : {EurocCamera(), FisheyeCamera()}) {
    Rng rng(3);
    for (int i = 0; i < 500; ++i) {
      const Eigen::Vector2d pixel(rng.Uniform(0, camera.width() - 1), rng.Uniform(0, camera.height() - 1));
      const Eigen::Vector2d back = camera.NormalizedToPixel(camera.PixelToNormalized(pixel));
      ASSERT_NEAR((back - pixel).norm(), 0.0, 1e-6) << camera.Describe();
    }
  }
}

TEST(Camera, RayThroughPixelProjectsBack) {
  const Camera camera = EurocCamera();
  const Eigen::Vector2d pixel(100.25, 400.5);
  const Eigen::Vector3d ray = camera.PixelToRay(pixel);
  EXPECT_NEAR(ray.norm(), 1.0, 1e-12);
  EXPECT_NEAR((*camera.Project(3.7 * ray) - pixel).norm(), 0.0, 1e-6);
}

TEST(Camera, AResizedCameraMatchesTheResizedImage) {
  const Camera camera = Camera::Pinhole(640, 480, 500, 500, 319.5, 239.5, -0.1, 0.02);
  const Camera half = camera.Resized(320, 240);
  EXPECT_EQ(half.width(), 320);
  EXPECT_EQ(half.height(), 240);
  EXPECT_NEAR(half.cx(), 159.5, 1e-12);
  const Eigen::Vector3d p(0.3, -0.2, 2.0);
  // Pixel centres scale about the image corner at (-0.5, -0.5), each axis by its own factor.
  const Camera wide = camera.Resized(960, 360);
  const Eigen::Vector2d full = *camera.Project(p), scaled = *wide.Project(p);
  EXPECT_NEAR(scaled.x() + 0.5, 1.5 * (full.x() + 0.5), 1e-9);
  EXPECT_NEAR(scaled.y() + 0.5, 0.75 * (full.y() + 0.5), 1e-9);
  EXPECT_NEAR(((*half.Project(p)).array() + 0.5).matrix().norm(), 0.5 * ((full.array() + 0.5).matrix().norm()), 1e-9);
  EXPECT_THROW(camera.Resized(0, 240), Error);
}

TEST(Camera, RejectsUnusableParameters) {
  EXPECT_THROW(Camera::Pinhole(640, 480, -1, 500, 320, 240), Error);
  EXPECT_THROW(Camera::Pinhole(640, 480, 500, 500, 2000, 240), Error);
  EXPECT_THROW(Camera::Pinhole(0, 480, 500, 500, 320, 240), Error);
  // Distortion that folds the image over itself cannot be inverted at the corners.
  EXPECT_THROW(Camera::Pinhole(640, 480, 300, 300, 320, 240, -3.0, 0, 0, 0, 0), Error);
  EXPECT_THROW(Camera(CameraModel::kPinholeRadTan, 640, 480, {1, 2, 3}), Error);
}

}  // namespace
}  // namespace stitch
