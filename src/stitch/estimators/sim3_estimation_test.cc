#include "stitch/estimators/sim3_estimation.h"

#include <random>

#include <gtest/gtest.h>

namespace stitch {
namespace {

TEST(Sim3Estimation, RecoversAKnownSimilarityFromNoisyMatchesWithOutliers) {
  const PinholeIntrinsics k{450, 450, 320, 240};
  // Submap B is submap A scaled by 2.5, turned and moved.
  const Sim3d truth(2.5, Eigen::Quaterniond(Eigen::AngleAxisd(0.7, Eigen::Vector3d(0.2, 1, 0.3).normalized())),
                    Eigen::Vector3d(3, -1, 0.5));
  const Rigid3d cam_a_from_a(Eigen::Quaterniond(Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitX())),
                             Eigen::Vector3d(0.2, 0, 0));
  // Keyframe B sees the same place: its pose in B is keyframe A's pose carried by the similarity
  // (and shifted a little).
  const Sim3d cam_a_in_b = truth * Sim3d(1.0, cam_a_from_a.Inverse().rotation, cam_a_from_a.Inverse().translation);
  const Rigid3d cam_b_from_b =
      Rigid3d(cam_a_in_b.rotation, cam_a_in_b.translation + Eigen::Vector3d(0.5, 0, 0)).Inverse();
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> uniform(-1, 1);
  std::normal_distribution<double> noise(0, 0.8);
  std::vector<Sim3Correspondence> pairs;
  int outliers = 0;
  while (pairs.size() < 150) {
    const Eigen::Vector3d in_cam_a(1.5 * uniform(rng), 1.0 * uniform(rng), 4 + uniform(rng));
    Sim3Correspondence c;
    c.point_a = cam_a_from_a.Inverse() * in_cam_a;
    c.point_b = truth * c.point_a;
    const Eigen::Vector3d in_cam_b = cam_b_from_b * c.point_b;
    if (in_cam_b.z() <= 0) continue;
    c.pixel_a = k.Project(in_cam_a) + Eigen::Vector2d(noise(rng), noise(rng));
    c.pixel_b = k.Project(in_cam_b) + Eigen::Vector2d(noise(rng), noise(rng));
    // Map point positions carry triangulation noise too.
    c.point_a += 0.005 * Eigen::Vector3d(uniform(rng), uniform(rng), uniform(rng));
    if (pairs.size() % 3 == 0) {  // a third are wrong matches
      c.point_b =
          truth * (cam_a_from_a.Inverse() * Eigen::Vector3d(1.5 * uniform(rng), uniform(rng), 4 + uniform(rng)));
      ++outliers;
    }
    pairs.push_back(c);
  }
  const auto estimate = EstimateSim3(pairs, cam_a_from_a, cam_b_from_b, k);
  ASSERT_TRUE(estimate);
  EXPECT_NEAR(estimate->b_from_a.scale, 2.5, 0.05);
  EXPECT_LT(estimate->b_from_a.rotation.angularDistance(truth.rotation), 0.01);
  EXPECT_LT((estimate->b_from_a.translation - truth.translation).norm(), 0.1);
  EXPECT_GE(estimate->num_inliers, 150 - outliers - 10);
  EXPECT_LE(estimate->num_inliers, 150 - outliers + 5);
}

TEST(Sim3Estimation, RefusesMatchesThatShareNoSimilarity) {
  const PinholeIntrinsics k{450, 450, 320, 240};
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> uniform(-1, 1);
  std::vector<Sim3Correspondence> pairs;
  for (int i = 0; i < 80; ++i) {
    Sim3Correspondence c;
    c.point_a = Eigen::Vector3d(uniform(rng), uniform(rng), 4 + uniform(rng));
    c.point_b = Eigen::Vector3d(uniform(rng), uniform(rng), 4 + uniform(rng));
    c.pixel_a = k.Project(c.point_a);
    c.pixel_b = k.Project(Eigen::Vector3d(uniform(rng), uniform(rng), 4));
    pairs.push_back(c);
  }
  EXPECT_FALSE(EstimateSim3(pairs, Rigid3d(), Rigid3d(), k));
}

}  // namespace
}  // namespace stitch
