#include "stitch/estimators/pnp.h"

#include <random>

#include <gtest/gtest.h>

namespace stitch {
namespace {

TEST(Pnp, RecoversAKnownPoseFromNoisyMatchesWithOutliers) {
  const PinholeIntrinsics k{450, 450, 320, 240};
  const Rigid3d truth(Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 0.5).normalized())),
                      Eigen::Vector3d(0.4, -0.2, 1.5));
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> uniform(-1, 1);
  std::normal_distribution<double> noise(0, 0.7);
  std::vector<PnpMatch> matches;
  int outliers = 0;
  while (matches.size() < 200) {
    const Eigen::Vector3d in_cam(2 * uniform(rng), 1.5 * uniform(rng), 4 + 2 * uniform(rng));
    const Eigen::Vector2d pixel = k.Project(in_cam);
    if (pixel.x() < 0 || pixel.x() > 640 || pixel.y() < 0 || pixel.y() > 480) continue;
    PnpMatch m;
    m.point_in_world = truth.Inverse() * in_cam;
    m.pixel = pixel + Eigen::Vector2d(noise(rng), noise(rng));
    if (matches.size() % 5 == 0) {  // 40% are wrong matches
      m.pixel = Eigen::Vector2d(320 + 300 * uniform(rng), 240 + 220 * uniform(rng));
      ++outliers;
    }
    if (matches.size() % 5 == 1) {
      m.pixel = Eigen::Vector2d(320 + 300 * uniform(rng), 240 + 220 * uniform(rng));
      ++outliers;
    }
    matches.push_back(m);
  }
  const auto result = EstimatePoseRansac(matches, k);
  ASSERT_TRUE(result);
  EXPECT_LT((result->cam_from_world.translation - truth.translation).norm(), 0.02);
  EXPECT_LT(result->cam_from_world.rotation.angularDistance(truth.rotation), 0.005);
  EXPECT_GE(result->num_inliers, 115);
  EXPECT_LE(result->num_inliers, 200 - outliers + 3);  // a random pixel may land near its truth
}

TEST(Pnp, RefusesWhenMatchesDoNotAgree) {
  const PinholeIntrinsics k{450, 450, 320, 240};
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> uniform(-1, 1);
  std::vector<PnpMatch> matches;
  for (int i = 0; i < 60; ++i) {
    PnpMatch m;
    m.point_in_world = Eigen::Vector3d(uniform(rng), uniform(rng), 5 + uniform(rng));
    m.pixel = Eigen::Vector2d(320 + 300 * uniform(rng), 240 + 220 * uniform(rng));
    matches.push_back(m);
  }
  EXPECT_FALSE(EstimatePoseRansac(matches, k));
  matches.resize(5);
  EXPECT_FALSE(EstimatePoseRansac(matches, k));
}

}  // namespace
}  // namespace stitch
