#pragma once
// A rolling shutter reads the image out row after row, so each row sees the scene a little later
// than the one above it: a camera moving or turning during the readout skews the image, and a
// tracker that takes the frame as one instant places its features wrong by up to the motion over
// the readout (the calm survey read out over 19 ms of each 50 ms frame: twice the ATE of a global
// shutter).
//
// UnrollRollingShutter moves each feature to where a global shutter at the frame's first row's
// time would have seen it, by the camera's motion per second (the motion model's) over its row's
// readout delay: to first order, a point at P in the camera moves by delay * (w x P + v). The
// rotation's part needs no depth; the translation's takes the depth where the feature is from a
// plane fitted to the last frame's tracked points in inverse depth (1/z affine in the image: exact
// for flat ground whatever the camera's tilt, so a forward camera's near rows and far horizon
// each get theirs). The features keep their descriptors; positions are corrected in the distorted
// image (in 1/8 pixel, as MakeFrame rounds them), so a keyframe made from the frame carries the
// corrected positions to every process.

#include "stitch/geometry/rigid3.h"
#include "stitch/map/frame.h"
#include "stitch/map/map.h"

namespace stitch {

// Inverse depth over the image, 1/z = a x + b y + c in normalized coordinates (x = (u - cx) / fx),
// held within [min, max] (no extrapolation past what was seen; min 0: far points move only with
// the rotation).
struct InverseDepthPlane {
  double a = 0, b = 0, c = 0;
  double min = 0, max = 0;
  bool valid() const { return max > 0; }
  double At(double x, double y) const { return std::clamp(a * x + b * y + c, min, max); }
  static InverseDepthPlane Constant(double depth) { return {0, 0, 1 / depth, 1 / depth, 1 / depth}; }
};

// The plane of a posed frame's tracked points (in `map`), fitted by least squares and refitted
// without the points farthest from it; invalid (max 0) with fewer than 10 points.
InverseDepthPlane FitInverseDepthPlane(const Map& map, const Frame& frame);

// `velocity`: cam_from_world(k) * world_from_cam(k - 1) over `velocity_interval_s` seconds;
// `line_delay_s`: readout delay from one row to the next. Returns the largest correction, pixels
// (0 when nothing moved).
double UnrollRollingShutter(Frame* frame, const Rigid3d& velocity, double velocity_interval_s, double line_delay_s,
                            const InverseDepthPlane& depth, const Undistorter& undistorter);

}  // namespace stitch
