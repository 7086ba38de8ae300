#pragma once
// A camera as the matching stages see it: the intrinsics of the ideal pinhole image, the feature
// pyramid's constants, and the undistortion table with the undistorted image's bounds. Built once
// per camera and shared by the tracker's and the mapper's stages. Immutable; thread-safe.

#include "stitch/geometry/camera.h"
#include "stitch/map/frame.h"
#include "stitch/map/matcher.h"

namespace stitch {

struct ViewGeometry {
  ViewGeometry() = default;
  ViewGeometry(const Camera& camera, const ScalePyramid& pyramid)
      : camera(camera), intrinsics(camera.Intrinsics()), pyramid(pyramid), undistorter(camera) {}

  // PredictInView within this camera's undistorted image.
  bool InView(const MapPoint& point, const Rigid3d& cam_from_world, PointInView* view) const {
    return PredictInView(point, cam_from_world, intrinsics, undistorter.min_x(), undistorter.min_y(),
                         undistorter.max_x(), undistorter.max_y(), pyramid, view);
  }

  Camera camera;
  PinholeIntrinsics intrinsics;
  ScalePyramid pyramid;
  Undistorter undistorter;
};

}  // namespace stitch
