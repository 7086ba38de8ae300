#pragma once
// The reprojection residual of bundle adjustment, with analytic derivatives. Parameters: the
// keyframe's pose cam_from_world as one block of 7 (PoseParameters: the rotation as an Eigen
// quaternion, x, y, z, w, then the translation), and the point in the world. Residual:
// sqrt(1/sigma^2) * (observed - projected), pixels. The derivatives are those of the rotation
// formula Eigen's quaternion product uses (X + 2w (v x X) + 2 v x (v x X)), so they hold for the
// quaternion as stored (Ceres keeps it on the unit sphere: PoseManifold). One pose block rather
// than a rotation and a translation block halves the blocks Ceres's Schur complement pairs up.

#include <ceres/ceres.h>
#include <ceres/product_manifold.h>
#include <Eigen/Core>
#include <Eigen/Geometry>

#include "stitch/geometry/rigid3.h"

namespace stitch {

// A pose as Ceres optimizes it: quaternion x, y, z, w, then translation x, y, z.
struct PoseParameters {
  double values[7];

  explicit PoseParameters(const Rigid3d& pose) {
    values[0] = pose.rotation.x();
    values[1] = pose.rotation.y();
    values[2] = pose.rotation.z();
    values[3] = pose.rotation.w();
    for (int i = 0; i < 3; ++i) values[4 + i] = pose.translation[i];
  }
  Rigid3d ToRigid() const {
    return Rigid3d(Eigen::Quaterniond(values[3], values[0], values[1], values[2]).normalized(),
                   Eigen::Vector3d(values[4], values[5], values[6]));
  }
  double* data() { return values; }
};

// The pose block's manifold: the quaternion stays on the unit sphere, the translation is free.
using PoseManifold = ceres::ProductManifold<ceres::EigenQuaternionManifold, ceres::EuclideanManifold<3>>;

class ReprojectionError : public ceres::SizedCostFunction<2, 7, 3> {
 public:
  ReprojectionError(const Eigen::Vector2d& observed, double sqrt_information, double fx, double fy, double cx,
                    double cy)
      : observed_(observed), sqrt_information_(sqrt_information), fx_(fx), fy_(fy), cx_(cx), cy_(cy) {}

  static ceres::CostFunction* Create(const Eigen::Vector2d& observed, double sqrt_information, double fx, double fy,
                                     double cx, double cy) {
    return new ReprojectionError(observed, sqrt_information, fx, fy, cx, cy);
  }

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    const Eigen::Map<const Eigen::Vector3d> v(parameters[0]);  // the quaternion's vector part
    const double w = parameters[0][3];
    const Eigen::Map<const Eigen::Vector3d> t(parameters[0] + 4);
    const Eigen::Map<const Eigen::Vector3d> x(parameters[1]);
    const Eigen::Vector3d v_cross_x = v.cross(x);
    const Eigen::Vector3d p = x + 2 * w * v_cross_x + 2 * v.cross(v_cross_x) + t;
    const double inverse_z = 1.0 / p.z();
    residuals[0] = sqrt_information_ * (observed_.x() - (fx_ * p.x() * inverse_z + cx_));
    residuals[1] = sqrt_information_ * (observed_.y() - (fy_ * p.y() * inverse_z + cy_));
    if (!jacobians) return true;
    // d residual / d p (the point in the camera), the residual's sign included.
    Eigen::Matrix<double, 2, 3> d_p;
    const double sx = sqrt_information_ * fx_ * inverse_z, sy = sqrt_information_ * fy_ * inverse_z;
    d_p << -sx, 0, sx * p.x() * inverse_z, 0, -sy, sy * p.y() * inverse_z;
    if (jacobians[0]) {
      // d p / d (v, w, t): v x (v x X) = v (v.X) - X (v.v).
      Eigen::Matrix<double, 3, 7> d_pose;
      d_pose.leftCols<3>() = -2 * w * Skew(x) + 2 * (v.dot(x) * Eigen::Matrix3d::Identity() + v * x.transpose() -
                                                     2 * x * v.transpose());
      d_pose.col(3) = 2 * v_cross_x;
      d_pose.rightCols<3>().setIdentity();
      Eigen::Map<Eigen::Matrix<double, 2, 7, Eigen::RowMajor>> jacobian(jacobians[0]);
      jacobian = d_p * d_pose;
    }
    if (jacobians[1]) {
      const Eigen::Matrix3d skew_v = Skew(v);
      const Eigen::Matrix3d d_x = Eigen::Matrix3d::Identity() + 2 * w * skew_v + 2 * skew_v * skew_v;
      Eigen::Map<Eigen::Matrix<double, 2, 3, Eigen::RowMajor>> d_point(jacobians[1]);
      d_point = d_p * d_x;
    }
    return true;
  }

 private:
  static Eigen::Matrix3d Skew(const Eigen::Vector3d& a) {
    Eigen::Matrix3d m;
    m << 0, -a.z(), a.y(), a.z(), 0, -a.x(), -a.y(), a.x(), 0;
    return m;
  }

  Eigen::Vector2d observed_;
  double sqrt_information_, fx_, fy_, cx_, cy_;
};

}  // namespace stitch
