#include "stitch/estimators/pose_optimizer.h"

#include <gtest/gtest.h>

#include "stitch/util/rng.h"

namespace stitch {
namespace {

const PinholeIntrinsics kCamera{450, 450, 319.5, 239.5};

TEST(PoseOptimizer, ConvergesFromAPerturbedPoseAndFindsTheOutliers) {
  Rng rng(1);
  const Rigid3d truth(Eigen::Quaterniond(Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, -2, 0.5).normalized())),
                      Eigen::Vector3d(0.3, -1, 2));
  std::vector<PoseObservation> observations;
  std::vector<bool> is_outlier;
  while (observations.size() < 300) {
    const Eigen::Vector3d in_cam(rng.Uniform(-4, 4), rng.Uniform(-3, 3), rng.Uniform(5, 12));
    const Eigen::Vector2d pixel = kCamera.Project(in_cam);
    if (pixel.x() < 0 || pixel.y() < 0 || pixel.x() > 639 || pixel.y() > 479) continue;
    const int level = rng.UniformInt(0, 3);
    const double scale = std::pow(1.2, level);
    PoseObservation o;
    o.point_in_world = truth.Inverse() * in_cam;
    o.inverse_sigma2 = 1.0 / (scale * scale);
    const bool outlier = rng.Uniform() < 0.2;
    o.pixel = outlier ? Eigen::Vector2d(rng.Uniform(0, 639), rng.Uniform(0, 479))
                      : pixel + 0.7 * scale * Eigen::Vector2d(rng.Normal(), rng.Normal());
    observations.push_back(o);
    is_outlier.push_back(outlier);
  }
  const Rigid3d perturbation(
      Eigen::Quaterniond(Eigen::AngleAxisd(5 * M_PI / 180, Eigen::Vector3d(0.3, 1, 0.2).normalized())),
      Eigen::Vector3d(0.3, -0.2, 0.25));
  const PoseOptimizerResult result = OptimizePose(observations, perturbation * truth, kCamera);
  ASSERT_TRUE(result.converged);
  // At the optimum: no worse than the true pose on the same observations (noise makes the
  // optimum differ from the truth by about 0.05 degrees here).
  double chi2_at_truth = 0;
  for (size_t i = 0; i < observations.size(); ++i) {
    if (!result.inlier[i]) continue;
    chi2_at_truth += (observations[i].pixel - kCamera.Project(truth * observations[i].point_in_world)).squaredNorm() *
                     observations[i].inverse_sigma2;
  }
  EXPECT_LE(result.final_chi2, chi2_at_truth);
  EXPECT_LT(result.cam_from_world.rotation.angularDistance(truth.rotation) * 180 / M_PI, 0.1);
  EXPECT_LT((result.cam_from_world.translation - truth.translation).norm(), 0.01);
  int wrong = 0;
  for (size_t i = 0; i < observations.size(); ++i) {
    // A random "outlier" can land near its true position; only true inliers must be kept.
    if (!is_outlier[i] && !result.inlier[i]) ++wrong;
  }
  EXPECT_LE(wrong, 5);
  EXPECT_LT(result.num_inliers, 260);
}

TEST(PoseOptimizer, ReportsFailureWithoutObservations) {
  EXPECT_FALSE(OptimizePose({}, Rigid3d(), kCamera).converged);
}

}  // namespace
}  // namespace stitch
