#include "stitch/geometry/similarity.h"

#include <Eigen/Geometry>
#include <Eigen/SVD>

#include "stitch/util/error.h"

namespace stitch {

Sim3d AlignPoints(const std::vector<Eigen::Vector3d>& points_in_a, const std::vector<Eigen::Vector3d>& points_in_b,
                  bool estimate_scale) {
  if (points_in_a.size() != points_in_b.size()) {
    throw Error(Str() << "AlignPoints: " << points_in_a.size() << " points in a but " << points_in_b.size() << " in b");
  }
  if (points_in_a.size() < 3) {
    throw Error(Str() << "AlignPoints: need at least 3 point pairs, got " << points_in_a.size());
  }
  Eigen::Matrix3Xd a(3, points_in_a.size());
  Eigen::Matrix3Xd b(3, points_in_b.size());
  for (size_t i = 0; i < points_in_a.size(); ++i) {
    a.col(i) = points_in_a[i];
    b.col(i) = points_in_b[i];
  }
  // Degenerate input (all points on a line) has a rank-1 spread and no unique rotation.
  const Eigen::Matrix3Xd centred = a.colwise() - a.rowwise().mean();
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(centred * centred.transpose());
  if (svd.singularValues()(1) <= 1e-12 * std::max(1.0, svd.singularValues()(0))) {
    throw Error("AlignPoints: the points are collinear or coincident; no unique alignment");
  }
  const Eigen::Matrix4d m = Eigen::umeyama(a, b, estimate_scale);
  const Eigen::Matrix3d scaled_rotation = m.topLeftCorner<3, 3>();
  const double scale = std::cbrt(scaled_rotation.determinant());
  const Eigen::Quaterniond rotation(scaled_rotation / scale);
  return Sim3d(scale, rotation.normalized(), m.topRightCorner<3, 1>());
}

}  // namespace stitch
