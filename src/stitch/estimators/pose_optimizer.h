#pragma once
// Pose-only optimization: the camera pose that best reprojects known 3D points onto their
// observed (undistorted) keypoints, with a Huber cost, in rounds that set aside outliers (as
// ORB-SLAM's PoseOptimization). Hand-written Gauss-Newton on SE(3): a 6x6 system per iteration,
// far cheaper than a general solver for a few hundred points.

#include <vector>

#include <Eigen/Core>

#include "stitch/geometry/camera.h"
#include "stitch/geometry/rigid3.h"

namespace stitch {

struct PoseObservation {
  Eigen::Vector2d pixel;  // undistorted keypoint
  Eigen::Vector3d point_in_world;
  double inverse_sigma2 = 1.0;  // 1 / (level scale)^2
};

struct PoseOptimizerOptions {
  int rounds = 4;
  int iterations_per_round = 10;
  double chi2_threshold = 5.991;  // 95% for 2 DoF: larger normalized errors are outliers
  int robust_rounds = 2;          // first rounds use the Huber cost, later ones plain least squares
};

struct PoseOptimizerResult {
  Rigid3d cam_from_world;
  std::vector<char> inlier;  // per observation
  int num_inliers = 0;
  double final_chi2 = 0;   // sum over inliers of normalized squared errors
  bool converged = false;  // false when the system was singular or the pose went bad
};

PoseOptimizerResult OptimizePose(const std::vector<PoseObservation>& observations, const Rigid3d& initial,
                                 const PinholeIntrinsics& intrinsics, const PoseOptimizerOptions& options = {});

// Rotation exp map (axis-angle vector to rotation).
Eigen::Quaterniond ExpSO3(const Eigen::Vector3d& omega);

}  // namespace stitch
