#include "stitch/estimators/triangulation.h"

#include <Eigen/SVD>

namespace stitch {

std::optional<Eigen::Vector3d> TriangulateDlt(const Rigid3d& cam1_from_world, const Eigen::Vector2d& n1,
                                              const Rigid3d& cam2_from_world, const Eigen::Vector2d& n2) {
  const Eigen::Matrix<double, 3, 4> p1 = cam1_from_world.Matrix3x4();
  const Eigen::Matrix<double, 3, 4> p2 = cam2_from_world.Matrix3x4();
  Eigen::Matrix4d a;
  a.row(0) = n1.x() * p1.row(2) - p1.row(0);
  a.row(1) = n1.y() * p1.row(2) - p1.row(1);
  a.row(2) = n2.x() * p2.row(2) - p2.row(0);
  a.row(3) = n2.y() * p2.row(2) - p2.row(1);
  const Eigen::JacobiSVD<Eigen::Matrix4d> svd(a, Eigen::ComputeFullV);
  const Eigen::Vector4d x = svd.matrixV().col(3);
  if (std::abs(x(3)) < 1e-12) return std::nullopt;
  const Eigen::Vector3d point = x.head<3>() / x(3);
  if (!point.allFinite()) return std::nullopt;
  return point;
}

double ParallaxCosine(const Eigen::Vector3d& point, const Eigen::Vector3d& centre1, const Eigen::Vector3d& centre2) {
  const Eigen::Vector3d r1 = point - centre1, r2 = point - centre2;
  return r1.dot(r2) / (r1.norm() * r2.norm());
}

}  // namespace stitch
