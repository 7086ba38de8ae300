#include "stitch/estimators/sim3_estimation.h"

#include <cmath>
#include <random>

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include "stitch/geometry/similarity.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

// Normalized squared reprojection error of `point` (in a submap) in a keyframe of that submap.
double ReprojectionChi2(const Eigen::Vector3d& point, const Rigid3d& cam_from_submap, const Eigen::Vector2d& pixel,
                        double sigma2, const PinholeIntrinsics& k) {
  const Eigen::Vector3d in_cam = cam_from_submap * point;
  if (in_cam.z() <= 0) return std::numeric_limits<double>::infinity();
  return (k.Project(in_cam) - pixel).squaredNorm() / sigma2;
}

// Reprojection of a point of one submap, carried by the similarity, into a keyframe of the other.
struct TransferError {
  TransferError(const Eigen::Vector3d& point, const Rigid3d& cam_from_submap, const Eigen::Vector2d& pixel,
                double sigma, const PinholeIntrinsics& k, bool inverse)
      : point(point), cam_from_submap(cam_from_submap), pixel(pixel), sigma(sigma), k(k), inverse(inverse) {}

  template <class T>
  bool operator()(const T* rotation, const T* translation, const T* log_scale, T* residual) const {
    // b_from_a = (exp(log_scale), rotation, translation); `inverse` carries points of B into A.
    const Eigen::Map<const Eigen::Quaternion<T>> q(rotation);
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> t(translation);
    const T s = ceres::exp(log_scale[0]);
    Eigen::Matrix<T, 3, 1> p = point.cast<T>();
    Eigen::Matrix<T, 3, 1> moved;
    if (!inverse) {
      moved = s * (q * p) + t;
    } else {
      moved = (q.conjugate() * (p - t)) / s;
    }
    const Eigen::Matrix<T, 3, 1> in_cam =
        cam_from_submap.rotation.cast<T>() * moved + cam_from_submap.translation.cast<T>();
    residual[0] = (T(k.fx) * in_cam.x() / in_cam.z() + T(k.cx) - T(pixel.x())) / T(sigma);
    residual[1] = (T(k.fy) * in_cam.y() / in_cam.z() + T(k.cy) - T(pixel.y())) / T(sigma);
    return true;
  }

  Eigen::Vector3d point;
  Rigid3d cam_from_submap;
  Eigen::Vector2d pixel;
  double sigma;
  PinholeIntrinsics k;
  bool inverse;
};

Sim3d Refine(const std::vector<Sim3Correspondence>& pairs, const std::vector<char>& inlier, const Sim3d& initial,
             const Rigid3d& cam_a_from_a, const Rigid3d& cam_b_from_b, const PinholeIntrinsics& k,
             const Sim3Options& options) {
  double rotation[4] = {initial.rotation.x(), initial.rotation.y(), initial.rotation.z(), initial.rotation.w()};
  double translation[3] = {initial.translation.x(), initial.translation.y(), initial.translation.z()};
  double log_scale = std::log(initial.scale);
  ceres::Problem problem;
  ceres::LossFunction* huber = new ceres::HuberLoss(std::sqrt(options.chi2_threshold));
  for (size_t i = 0; i < pairs.size(); ++i) {
    if (!inlier[i]) continue;
    const Sim3Correspondence& c = pairs[i];
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<TransferError, 2, 4, 3, 1>(new TransferError(
                                 c.point_a, cam_b_from_b, c.pixel_b, std::sqrt(c.sigma2_b), k, false)),
                             huber, rotation, translation, &log_scale);
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<TransferError, 2, 4, 3, 1>(
                                 new TransferError(c.point_b, cam_a_from_a, c.pixel_a, std::sqrt(c.sigma2_a), k, true)),
                             huber, rotation, translation, &log_scale);
  }
  if (problem.NumResidualBlocks() == 0) return initial;
  problem.SetManifold(rotation, new ceres::EigenQuaternionManifold);
  ceres::Solver::Options solver;
  solver.max_num_iterations = options.refine_iterations;
  solver.linear_solver_type = ceres::DENSE_QR;
  solver.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(solver, &problem, &summary);
  return Sim3d(std::exp(log_scale), Eigen::Quaterniond(rotation[3], rotation[0], rotation[1], rotation[2]).normalized(),
               Eigen::Vector3d(translation[0], translation[1], translation[2]));
}

}  // namespace

std::vector<char> Sim3Inliers(const std::vector<Sim3Correspondence>& pairs, const Sim3d& b_from_a,
                              const Rigid3d& cam_a_from_a, const Rigid3d& cam_b_from_b,
                              const PinholeIntrinsics& intrinsics, double chi2_threshold) {
  const Sim3d a_from_b = b_from_a.Inverse();
  std::vector<char> inlier(pairs.size(), 0);
  for (size_t i = 0; i < pairs.size(); ++i) {
    const Sim3Correspondence& c = pairs[i];
    inlier[i] =
        ReprojectionChi2(b_from_a * c.point_a, cam_b_from_b, c.pixel_b, c.sigma2_b, intrinsics) < chi2_threshold &&
        ReprojectionChi2(a_from_b * c.point_b, cam_a_from_a, c.pixel_a, c.sigma2_a, intrinsics) < chi2_threshold;
  }
  return inlier;
}

std::optional<Sim3Estimate> EstimateSim3(const std::vector<Sim3Correspondence>& pairs, const Rigid3d& cam_a_from_a,
                                         const Rigid3d& cam_b_from_b, const PinholeIntrinsics& intrinsics,
                                         const Sim3Options& options, int* inliers) {
  const int n = static_cast<int>(pairs.size());
  if (n < std::max(3, options.min_inliers)) return std::nullopt;
  std::mt19937_64 rng(options.seed);
  std::uniform_int_distribution<int> pick(0, n - 1);
  Sim3Estimate best;
  for (int iteration = 0; iteration < options.iterations; ++iteration) {
    int i = pick(rng), j = pick(rng), m = pick(rng);
    if (i == j || j == m || i == m) continue;
    Sim3d b_from_a;
    try {
      b_from_a = AlignPoints({pairs[i].point_a, pairs[j].point_a, pairs[m].point_a},
                             {pairs[i].point_b, pairs[j].point_b, pairs[m].point_b});
    } catch (const Error&) {
      continue;  // collinear sample
    }
    if (!(b_from_a.scale > 0) || !std::isfinite(b_from_a.scale)) continue;
    std::vector<char> inlier =
        Sim3Inliers(pairs, b_from_a, cam_a_from_a, cam_b_from_b, intrinsics, options.chi2_threshold);
    const int count = static_cast<int>(std::count(inlier.begin(), inlier.end(), 1));
    if (count > best.num_inliers) {
      best.b_from_a = b_from_a;
      best.inlier = std::move(inlier);
      best.num_inliers = count;
    }
  }
  if (inliers) *inliers = best.num_inliers;
  if (best.num_inliers < options.min_inliers) return std::nullopt;
  // Refine on the inliers, then judge every pair again with the refined similarity.
  Sim3Estimate refined;
  refined.b_from_a = Refine(pairs, best.inlier, best.b_from_a, cam_a_from_a, cam_b_from_b, intrinsics, options);
  refined.inlier = Sim3Inliers(pairs, refined.b_from_a, cam_a_from_a, cam_b_from_b, intrinsics, options.chi2_threshold);
  refined.num_inliers = static_cast<int>(std::count(refined.inlier.begin(), refined.inlier.end(), 1));
  if (inliers) *inliers = refined.num_inliers;
  if (refined.num_inliers < options.min_inliers) return std::nullopt;
  return refined;
}

}  // namespace stitch
