#pragma once
// The reprojection residual of bundle adjustment, for Ceres autodiff. Parameters: the keyframe's
// rotation as an Eigen quaternion (x, y, z, w in memory, cam_from_world), its translation, and
// the point in the world. Residual: sqrt(1/sigma^2) * (observed - projected), pixels.

#include <ceres/ceres.h>
#include <Eigen/Core>
#include <Eigen/Geometry>

namespace stitch {

struct ReprojectionError {
  ReprojectionError(const Eigen::Vector2d& observed, double sqrt_information, double fx, double fy, double cx,
                    double cy)
      : observed(observed), sqrt_information(sqrt_information), fx(fx), fy(fy), cx(cx), cy(cy) {}

  template <typename T>
  bool operator()(const T* rotation, const T* translation, const T* point, T* residual) const {
    const Eigen::Map<const Eigen::Quaternion<T>> q(rotation);
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> t(translation);
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> x(point);
    const Eigen::Matrix<T, 3, 1> p = q * x + t;
    residual[0] = T(sqrt_information) * (T(observed.x()) - (T(fx) * p.x() / p.z() + T(cx)));
    residual[1] = T(sqrt_information) * (T(observed.y()) - (T(fy) * p.y() / p.z() + T(cy)));
    return true;
  }

  static ceres::CostFunction* Create(const Eigen::Vector2d& observed, double sqrt_information, double fx, double fy,
                                     double cx, double cy) {
    return new ceres::AutoDiffCostFunction<ReprojectionError, 2, 4, 3, 3>(
        new ReprojectionError(observed, sqrt_information, fx, fy, cx, cy));
  }

  Eigen::Vector2d observed;
  double sqrt_information, fx, fy, cx, cy;
};

}  // namespace stitch
