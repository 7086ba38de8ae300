#include "stitch/estimators/pnp.h"

#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>

namespace stitch {

std::optional<PnpResult> EstimatePoseRansac(const std::vector<PnpMatch>& matches, const PinholeIntrinsics& intrinsics,
                                            const PnpOptions& options) {
  if (matches.size() < 6 || static_cast<int>(matches.size()) < options.min_inliers) return std::nullopt;
  std::vector<cv::Point3d> object;
  std::vector<cv::Point2d> image;
  for (const PnpMatch& m : matches) {
    object.emplace_back(m.point_in_world.x(), m.point_in_world.y(), m.point_in_world.z());
    image.emplace_back(m.pixel.x(), m.pixel.y());
  }
  cv::Mat k;
  cv::eigen2cv(intrinsics.K(), k);
  cv::Mat rvec, tvec;
  std::vector<int> sample_inliers;
  // RANSAC with the level-0 threshold, then the inliers are re-judged per level below.
  const bool found = cv::solvePnPRansac(object, image, k, cv::noArray(), rvec, tvec, false, options.iterations,
                                        static_cast<float>(options.max_error_px), options.confidence, sample_inliers,
                                        cv::SOLVEPNP_EPNP);
  if (!found || static_cast<int>(sample_inliers.size()) < options.min_inliers) return std::nullopt;
  cv::Mat rotation;
  cv::Rodrigues(rvec, rotation);
  Eigen::Matrix3d r;
  Eigen::Vector3d t;
  cv::cv2eigen(rotation, r);
  cv::cv2eigen(tvec, t);
  PnpResult result;
  result.cam_from_world = Rigid3d(Eigen::Quaterniond(r), t);
  result.inlier.assign(matches.size(), 0);
  for (size_t i = 0; i < matches.size(); ++i) {
    const Eigen::Vector3d in_cam = result.cam_from_world * matches[i].point_in_world;
    if (in_cam.z() <= 0) continue;
    const double error = (intrinsics.Project(in_cam) - matches[i].pixel).norm();
    if (error <= options.max_error_px * matches[i].level_scale) {
      result.inlier[i] = 1;
      ++result.num_inliers;
    }
  }
  if (result.num_inliers < options.min_inliers) return std::nullopt;
  return result;
}

}  // namespace stitch
