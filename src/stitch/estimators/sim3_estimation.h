#pragma once
// The similarity between two submaps from matched map points (monocular scale differs per
// submap): Umeyama on 3 point pairs inside RANSAC, inliers judged by reprojection in both
// keyframes (as ORB-SLAM's Sim3Solver), then a refinement with Ceres and a Huber cost over the
// inliers' reprojection errors both ways.

#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "stitch/geometry/camera.h"
#include "stitch/geometry/rigid3.h"

namespace stitch {

// A map point seen by keyframe A (in submap A) matched to one seen by keyframe B (in submap B).
struct Sim3Correspondence {
  Eigen::Vector3d point_a;  // in submap A's frame
  Eigen::Vector3d point_b;  // in submap B's frame
  Eigen::Vector2d pixel_a;  // its undistorted keypoint in keyframe A
  Eigen::Vector2d pixel_b;  // ...in keyframe B
  double sigma2_a = 1.0;    // variance of that keypoint's level, px^2
  double sigma2_b = 1.0;
};

struct Sim3Options {
  int iterations = 300;
  double chi2_threshold = 9.21;  // 99% for 2 DoF: a pair is an inlier when both reprojections are within
  int min_inliers = 20;
  int refine_iterations = 10;
  uint64_t seed = 1;  // RANSAC samples are deterministic
};

struct Sim3Estimate {
  Sim3d b_from_a;
  std::vector<char> inlier;  // per correspondence
  int num_inliers = 0;
};

// The keyframes' poses in their own submaps (`cam_a_from_a`, `cam_b_from_b`) and the shared
// intrinsics. nullopt when fewer than `min_inliers` pairs agree, before or after refinement;
// `inliers` (optional) receives the best count found either way.
std::optional<Sim3Estimate> EstimateSim3(const std::vector<Sim3Correspondence>& pairs, const Rigid3d& cam_a_from_a,
                                         const Rigid3d& cam_b_from_b, const PinholeIntrinsics& intrinsics,
                                         const Sim3Options& options = {}, int* inliers = nullptr);

// Which pairs `b_from_a` explains (both reprojections within the threshold).
std::vector<char> Sim3Inliers(const std::vector<Sim3Correspondence>& pairs, const Sim3d& b_from_a,
                              const Rigid3d& cam_a_from_a, const Rigid3d& cam_b_from_b,
                              const PinholeIntrinsics& intrinsics, double chi2_threshold);

}  // namespace stitch
