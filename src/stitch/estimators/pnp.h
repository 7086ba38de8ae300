#pragma once
// Absolute pose from 2D-3D matches with outliers: EPnP inside RANSAC (OpenCV's solvePnPRansac),
// the first step of relocalization. The pose is then refined by OptimizePose.

#include <optional>
#include <vector>

#include <Eigen/Core>

#include "stitch/geometry/camera.h"
#include "stitch/geometry/rigid3.h"

namespace stitch {

struct PnpOptions {
  int iterations = 300;
  double max_error_px = 4.0;  // inlier threshold at pyramid level 0 (scaled by each match's level)
  double confidence = 0.99;
  int min_inliers = 10;
};

struct PnpMatch {
  Eigen::Vector2d pixel;  // undistorted keypoint
  Eigen::Vector3d point_in_world;
  double level_scale = 1.0;  // scale of the keypoint's pyramid level
};

struct PnpResult {
  Rigid3d cam_from_world;
  std::vector<char> inlier;  // per match
  int num_inliers = 0;
};

// nullopt when fewer than `min_inliers` matches agree on a pose (or there are fewer than 6).
std::optional<PnpResult> EstimatePoseRansac(const std::vector<PnpMatch>& matches, const PinholeIntrinsics& intrinsics,
                                            const PnpOptions& options = {});

}  // namespace stitch
