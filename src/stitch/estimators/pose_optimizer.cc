#include "stitch/estimators/pose_optimizer.h"

#include <cmath>

#include <Eigen/Cholesky>

namespace stitch {

Eigen::Quaterniond ExpSO3(const Eigen::Vector3d& omega) {
  const double angle = omega.norm();
  if (angle < 1e-12) return Eigen::Quaterniond(1, 0.5 * omega.x(), 0.5 * omega.y(), 0.5 * omega.z()).normalized();
  return Eigen::Quaterniond(Eigen::AngleAxisd(angle, omega / angle));
}

PoseOptimizerResult OptimizePose(const std::vector<PoseObservation>& observations, const Rigid3d& initial,
                                 const PinholeIntrinsics& k, const PoseOptimizerOptions& options) {
  PoseOptimizerResult result;
  result.cam_from_world = initial;
  result.inlier.assign(observations.size(), 1);
  const double huber = std::sqrt(options.chi2_threshold);
  Eigen::Matrix3d rotation = initial.RotationMatrix();
  Eigen::Vector3d translation = initial.translation;
  bool ok = true;
  for (int round = 0; round < options.rounds && ok; ++round) {
    const bool robust = round < options.robust_rounds;
    for (int iteration = 0; iteration < options.iterations_per_round; ++iteration) {
      Eigen::Matrix<double, 6, 6> h = Eigen::Matrix<double, 6, 6>::Zero();
      Eigen::Matrix<double, 6, 1> b = Eigen::Matrix<double, 6, 1>::Zero();
      int used = 0;
      for (size_t i = 0; i < observations.size(); ++i) {
        if (!result.inlier[i]) continue;
        const PoseObservation& o = observations[i];
        const Eigen::Vector3d p = rotation * o.point_in_world + translation;
        if (p.z() <= 1e-9) continue;
        const double inv_z = 1.0 / p.z();
        const Eigen::Vector2d predicted(k.fx * p.x() * inv_z + k.cx, k.fy * p.y() * inv_z + k.cy);
        const Eigen::Vector2d residual = o.pixel - predicted;
        const double chi2 = residual.squaredNorm() * o.inverse_sigma2;
        double weight = o.inverse_sigma2;
        if (robust && chi2 > options.chi2_threshold) weight *= huber / std::sqrt(chi2);
        // d(predicted)/d(p) and d(p)/d(delta) for the update p' = Exp(omega) p + v.
        Eigen::Matrix<double, 2, 3> dproj;
        dproj << k.fx * inv_z, 0, -k.fx * p.x() * inv_z * inv_z, 0, k.fy * inv_z, -k.fy * p.y() * inv_z * inv_z;
        Eigen::Matrix<double, 3, 6> dp;
        dp << 0, p.z(), -p.y(), 1, 0, 0,  // -[p]x for omega, identity for v
            -p.z(), 0, p.x(), 0, 1, 0, p.y(), -p.x(), 0, 0, 0, 1;
        const Eigen::Matrix<double, 2, 6> j = dproj * dp;  // d(predicted)/d(delta)
        h.noalias() += weight * j.transpose() * j;
        b.noalias() += weight * j.transpose() * residual;
        ++used;
      }
      if (used < 3) {
        ok = false;
        break;
      }
      const Eigen::LDLT<Eigen::Matrix<double, 6, 6>> solver(h);
      if (solver.info() != Eigen::Success) {
        ok = false;
        break;
      }
      const Eigen::Matrix<double, 6, 1> delta = solver.solve(b);
      if (!delta.allFinite()) {
        ok = false;
        break;
      }
      const Eigen::Matrix3d update = ExpSO3(delta.head<3>()).toRotationMatrix();
      rotation = update * rotation;
      translation = update * translation + delta.tail<3>();
      if (delta.squaredNorm() < 1e-16) break;
    }
    // Classify observations with the round's pose; outliers sit out the next round but are
    // re-classified (and may come back) after it.
    result.num_inliers = 0;
    result.final_chi2 = 0;
    for (size_t i = 0; i < observations.size(); ++i) {
      const PoseObservation& o = observations[i];
      const Eigen::Vector3d p = rotation * o.point_in_world + translation;
      const double chi2 = p.z() > 0 ? (o.pixel - k.Project(p)).squaredNorm() * o.inverse_sigma2 : 1e18;
      result.inlier[i] = chi2 <= options.chi2_threshold;
      if (result.inlier[i]) {
        ++result.num_inliers;
        result.final_chi2 += chi2;
      }
    }
  }
  Eigen::Quaterniond q(rotation);
  result.cam_from_world = Rigid3d(q.normalized(), translation);
  result.converged = ok && result.cam_from_world.translation.allFinite() && result.num_inliers >= 3;
  return result;
}

}  // namespace stitch
