#pragma once
// Renders a SyntheticWorld through a pinhole camera: a z-buffer rasterizer with perspective-
// correct, trilinearly mip-mapped texturing, so views are correct in perspective and occlusion
// and do not alias as the UAV climbs. Distortion, when the camera has some, is applied after.
// A Renderer holds per-call buffers only; Render() is const and may run in several threads.

#include <functional>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "stitch/geometry/camera.h"
#include "stitch/geometry/rigid3.h"
#include "stitch/synthetic/world.h"

namespace stitch {

class Renderer {
 public:
  // Keeps references: `world` must outlive the renderer.
  Renderer(const SyntheticWorld& world, const Camera& camera);

  // A CV_8UC1 image of the world seen from `cam_from_world`. When `depth` is given it receives
  // CV_32F z in camera coordinates per pixel (0 where nothing was drawn) of the pinhole image:
  // for a distorted camera, that of the canvas the distorted image is sampled from (canvas()).
  cv::Mat Render(const Rigid3d& cam_from_world, cv::Mat* depth = nullptr) const;
  const cv::Rect& canvas() const { return canvas_; }

 private:
  cv::Mat RenderPinhole(const Rigid3d& cam_from_world, cv::Mat* depth) const;

  const SyntheticWorld& world_;
  Camera camera_;
  cv::Mat distort_map_x_, distort_map_y_;  // pinhole canvas -> distorted image, when needed
  // Where the pinhole image is rendered, in the camera's pixels: the image itself, or for a
  // distorted camera whatever its pixels see.
  cv::Rect canvas_;
};

// The world's true orthophoto: what straight down shows at each of `size` pixels, whose centre
// (col, row) lies at world x, y `world_at(col, row)`, `pixel_m` metres a side (the texture's mip
// level for it): roofs where buildings stand, the shaded terrain elsewhere; no walls, no relief
// displacement. CV_8UC1; 0 off the world.
cv::Mat RenderOrthophoto(const SyntheticWorld& world, const cv::Size& size, double pixel_m,
                         const std::function<Eigen::Vector2d(int col, int row)>& world_at);

}  // namespace stitch
