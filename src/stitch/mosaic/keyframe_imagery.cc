#include "stitch/mosaic/keyframe_imagery.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "stitch/util/error.h"

namespace stitch {

bool KeyframeImageOptions::Check(std::string* why) const {
  const auto fail = [&](const char* text) { return *why = text, false; };
  if (max_side_px < 16 || max_side_px > 8192) return fail("max_side_px must be in [16, 8192]");
  if (jpeg_quality < 1 || jpeg_quality > 100) return fail("jpeg_quality must be in [1, 100]");
  if (!(min_view_change >= 0 && min_view_change <= 10)) return fail("min_view_change must be in [0, 10]");
  return true;
}

bool KeyframeImagePicker::Take(int64_t submap, const Rigid3d& world_from_cam, const Camera& camera) {
  if (!options_.send) return false;
  if (submap_ != submap) {
    submap_ = submap;
    last_sent_ = world_from_cam;
    return true;
  }
  // The footprint at unit depth, and the field of view, across the image's narrower side (the one
  // a survey flies along, so its overlap is what it is planned by).
  const double footprint = std::min(camera.width() / camera.fx(), camera.height() / camera.fy());
  const double field_of_view = 2.0 * std::atan(0.5 * footprint);
  const double moved = (world_from_cam.translation - last_sent_.translation).norm() / footprint;
  const double turned =
      Eigen::AngleAxisd(last_sent_.rotation.conjugate() * world_from_cam.rotation).angle() / field_of_view;
  if (std::max(moved, turned) < options_.min_view_change) return false;
  last_sent_ = world_from_cam;
  return true;
}

std::vector<uint8_t> EncodeKeyframePicture(const cv::Mat& image, const KeyframeImageOptions& options, cv::Size* size) {
  if (image.empty()) throw Error("a keyframe picture of an empty image");
  cv::Mat picture = image;
  const int side = std::max(image.cols, image.rows);
  if (side > options.max_side_px) {
    const double scale = static_cast<double>(options.max_side_px) / side;
    cv::resize(image, picture,
               cv::Size(std::max(1, static_cast<int>(std::lround(image.cols * scale))),
                        std::max(1, static_cast<int>(std::lround(image.rows * scale)))),
               0, 0, cv::INTER_AREA);
  }
  std::vector<uint8_t> jpeg;
  if (!cv::imencode(".jpg", picture, jpeg, {cv::IMWRITE_JPEG_QUALITY, options.jpeg_quality})) {
    throw Error("a keyframe picture could not be compressed");
  }
  if (size) *size = picture.size();
  return jpeg;
}

}  // namespace stitch
