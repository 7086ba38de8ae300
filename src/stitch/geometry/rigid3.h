#pragma once
// Rigid and similarity transforms. A variable's name says its frames: `cam_from_world` maps a
// point in world coordinates to camera coordinates: point_in_cam = cam_from_world * point_in_world
// (x_in_b = R * x_in_a + t for b_from_a, as in COLMAP's Rigid3d).

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace stitch {

struct Rigid3d {
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();

  Rigid3d() = default;
  Rigid3d(const Eigen::Quaterniond& r, const Eigen::Vector3d& t) : rotation(r), translation(t) {}

  Eigen::Vector3d operator*(const Eigen::Vector3d& point) const { return rotation * point + translation; }
  // c_from_a = c_from_b * b_from_a
  Rigid3d operator*(const Rigid3d& b_from_a) const {
    return {(rotation * b_from_a.rotation).normalized(), rotation * b_from_a.translation + translation};
  }
  Rigid3d Inverse() const {
    const Eigen::Quaterniond inverse = rotation.conjugate();
    return {inverse, -(inverse * translation)};
  }
  Eigen::Matrix3d RotationMatrix() const { return rotation.toRotationMatrix(); }
  Eigen::Matrix<double, 3, 4> Matrix3x4() const {
    Eigen::Matrix<double, 3, 4> m;
    m << RotationMatrix(), translation;
    return m;
  }
  // For a cam_from_world transform: the camera centre in world coordinates.
  Eigen::Vector3d CentreInWorld() const { return -(rotation.conjugate() * translation); }
  // For a cam2_from_cam1 transform: the essential matrix [t]x R, x2' E x1 = 0 for the two
  // cameras' normalized rays to one point (scaled as the translation is).
  Eigen::Matrix3d EssentialMatrix() const {
    Eigen::Matrix3d t_cross;
    t_cross << 0, -translation.z(), translation.y(), translation.z(), 0, -translation.x(), -translation.y(),
        translation.x(), 0;
    return t_cross * RotationMatrix();
  }
};

struct Sim3d {
  double scale = 1.0;
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();

  Sim3d() = default;
  Sim3d(double s, const Eigen::Quaterniond& r, const Eigen::Vector3d& t) : scale(s), rotation(r), translation(t) {}

  Eigen::Vector3d operator*(const Eigen::Vector3d& point) const { return scale * (rotation * point) + translation; }
  Sim3d operator*(const Sim3d& b_from_a) const {
    return {scale * b_from_a.scale, (rotation * b_from_a.rotation).normalized(),
            scale * (rotation * b_from_a.translation) + translation};
  }
  Sim3d Inverse() const {
    const Eigen::Quaterniond inverse = rotation.conjugate();
    return {1.0 / scale, inverse, -(inverse * translation) / scale};
  }
  Eigen::Matrix4d Matrix() const {
    Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
    m.topLeftCorner<3, 3>() = scale * rotation.toRotationMatrix();
    m.topRightCorner<3, 1>() = translation;
    return m;
  }
};

// A camera pose carried into another frame by a similarity: world_from_cam = world_from_submap *
// submap_from_cam (the scale goes into the translation; the camera stays metric-free).
inline Rigid3d TransformPose(const Sim3d& world_from_submap, const Rigid3d& submap_from_cam) {
  return Rigid3d((world_from_submap.rotation * submap_from_cam.rotation).normalized(),
                 world_from_submap * submap_from_cam.translation);
}

// Rotation angle of a quaternion, radians in [0, pi].
inline double RotationAngle(const Eigen::Quaterniond& q) {
  return 2.0 * std::atan2(q.vec().norm(), std::abs(q.w()));
}

}  // namespace stitch
