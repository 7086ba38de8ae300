#pragma once
// Map initialization from two views (monocular). A homography and an essential matrix are
// estimated with RANSAC in parallel and scored as in ORB-SLAM (sum over matches of the chi-square
// margin of their transfer / epipolar errors); the homography is chosen when it explains at
// least 40% of the total score, as for a UAV over nearly flat ground or a low-parallax motion.
// The motion is recovered from the chosen model (every decomposition tested by triangulation:
// points in front of both cameras, small reprojection error, enough parallax) and accepted only
// when one solution is clearly the best. Translation has unit length.

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "stitch/geometry/camera.h"
#include "stitch/geometry/rigid3.h"

namespace stitch {

struct TwoViewOptions {
  double sigma_px = 1.0;          // keypoint noise at level 0
  double min_parallax_deg = 1.0;  // the 50th best parallax must reach this
  int min_triangulated = 50;
  double homography_ratio = 0.40;  // choose H when SH / (SH + SF) exceeds this
  double min_good_fraction = 0.9;  // of the chosen model's inliers, triangulated well

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("sigma_px", sigma_px, "keypoint noise at level 0, pixels");
    v("min_parallax_deg", min_parallax_deg, "parallax the 50th best point must reach, degrees");
    v("min_triangulated", min_triangulated, "points the initial map needs");
    v("homography_ratio", homography_ratio, "choose the homography when its share of the score exceeds this");
    v("min_good_fraction", min_good_fraction, "fraction of model inliers that must triangulate well");
  }
  bool Check(std::string* why) const;
};

struct TwoViewResult {
  Rigid3d cam2_from_cam1;
  std::vector<Eigen::Vector3d> points_in_cam1;  // per match; meaningful where triangulated
  std::vector<char> triangulated;               // per match
  bool used_homography = false;
  double homography_share = 0;  // SH / (SH + SF): the homography's share of the two models' scores
  double parallax_deg = 0;
  int num_triangulated = 0;
};

// `pixels1[i]` and `pixels2[i]` are matched undistorted pixels. Empty with `why` set when the
// views do not allow a reliable initialization (too few matches, too little parallax, ambiguous);
// past the scoring, `why` names the model chosen and the homography's share of the score.
// `essential_only` (a camera moving toward the scene) takes the essential matrix whatever the
// homography's share: a refusal then waits for the parallax it needs.
std::optional<TwoViewResult> InitializeTwoView(const std::vector<Eigen::Vector2d>& pixels1,
                                               const std::vector<Eigen::Vector2d>& pixels2,
                                               const PinholeIntrinsics& intrinsics, const TwoViewOptions& options,
                                               std::string* why, bool essential_only = false);

}  // namespace stitch
