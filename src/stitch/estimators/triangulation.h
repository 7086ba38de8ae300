#pragma once
// Two-view triangulation.

#include <optional>

#include <Eigen/Core>

#include "stitch/geometry/rigid3.h"

namespace stitch {

// Linear (DLT) triangulation from normalized image coordinates (x/z, y/z) in two cameras given
// as cam_from_world. Empty when the system is degenerate (rays parallel, point at infinity).
std::optional<Eigen::Vector3d> TriangulateDlt(const Rigid3d& cam1_from_world, const Eigen::Vector2d& normalized1,
                                              const Rigid3d& cam2_from_world, const Eigen::Vector2d& normalized2);

// Cosine of the angle between the rays from the two camera centres to `point_in_world`.
double ParallaxCosine(const Eigen::Vector3d& point_in_world, const Eigen::Vector3d& centre1,
                      const Eigen::Vector3d& centre2);

}  // namespace stitch
