#include "stitch/geometry/similarity.h"

#include <gtest/gtest.h>

#include "stitch/util/error.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

Sim3d KnownSim3() {
  return Sim3d(2.5, Eigen::Quaterniond(Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized())),
               Eigen::Vector3d(10, -4, 2));
}

TEST(AlignPoints, RecoversAKnownSimilarityExactly) {
  Rng rng(1);
  const Sim3d b_from_a = KnownSim3();
  std::vector<Eigen::Vector3d> a, b;
  for (int i = 0; i < 50; ++i) {
    a.emplace_back(rng.Uniform(-5, 5), rng.Uniform(-5, 5), rng.Uniform(-5, 5));
    b.push_back(b_from_a * a.back());
  }
  const Sim3d estimate = AlignPoints(a, b);
  EXPECT_NEAR(estimate.scale, 2.5, 1e-9);
  EXPECT_NEAR(estimate.rotation.angularDistance(b_from_a.rotation), 0.0, 1e-9);
  EXPECT_NEAR((estimate.translation - b_from_a.translation).norm(), 0.0, 1e-8);
}

TEST(AlignPoints, RigidModeKeepsUnitScale) {
  const Sim3d b_from_a = KnownSim3();
  std::vector<Eigen::Vector3d> a{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}}, b;
  for (const auto& p : a) b.push_back(b_from_a * p);
  EXPECT_DOUBLE_EQ(AlignPoints(a, b, false).scale, 1.0);
}

TEST(AlignPoints, RejectsDegenerateInput) {
  std::vector<Eigen::Vector3d> line{{0, 0, 0}, {1, 1, 1}, {2, 2, 2}, {3, 3, 3}};
  EXPECT_THROW(AlignPoints(line, line), Error);
  EXPECT_THROW(AlignPoints({{0, 0, 0}, {1, 0, 0}}, {{0, 0, 0}, {1, 0, 0}}), Error);
}

TEST(Rigid3d, ComposesAndInverts) {
  const Rigid3d b_from_a(Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ())),
                         Eigen::Vector3d(1, 2, 3));
  const Rigid3d c_from_b(Eigen::Quaterniond(Eigen::AngleAxisd(-1.1, Eigen::Vector3d::UnitX())),
                         Eigen::Vector3d(-1, 0, 5));
  const Eigen::Vector3d p(0.5, -0.25, 2);
  EXPECT_NEAR(((c_from_b * b_from_a) * p - c_from_b * (b_from_a * p)).norm(), 0, 1e-12);
  EXPECT_NEAR((b_from_a.Inverse() * (b_from_a * p) - p).norm(), 0, 1e-12);
  const Sim3d s = KnownSim3();
  EXPECT_NEAR((s.Inverse() * (s * p) - p).norm(), 0, 1e-12);
}

}  // namespace
}  // namespace stitch
