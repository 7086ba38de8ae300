#pragma once
// Closed-form alignment of corresponding 3D points (Umeyama 1991): finds b_from_a minimizing
// sum |b_i - (s R a_i + t)|^2, with s fixed to 1 when `estimate_scale` is false.

#include <vector>

#include <Eigen/Core>

#include "stitch/geometry/rigid3.h"

namespace stitch {

// Needs at least 3 non-collinear pairs; throws stitch::Error otherwise.
Sim3d AlignPoints(const std::vector<Eigen::Vector3d>& points_in_a, const std::vector<Eigen::Vector3d>& points_in_b,
                  bool estimate_scale = true);

}  // namespace stitch
