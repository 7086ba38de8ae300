#pragma once
// Which keyframes' pictures the aircraft sends to the ground for its orthomosaic, and how: a
// keyframe is sent where its view has moved on enough since the last one sent (so the pictures
// cover the ground with some overlap, not once per keyframe), reduced and JPEG-compressed.

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "stitch/geometry/camera.h"
#include "stitch/geometry/rigid3.h"

namespace stitch {

struct KeyframeImageOptions {
  bool send = true;
  int max_side_px = 640;  // the picture is reduced to at most this many pixels a side
  int jpeg_quality = 75;
  // A keyframe's picture is sent when its camera moved by at least this share of the picture's
  // footprint (at the submap's scene depth, its unit) or turned by this share of the field of view
  // since the last one sent in its submap; a submap's first keyframe always.
  double min_view_change = 0.25;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("send", send, "send reduced pictures of keyframes to the ground (its orthomosaic; behind all else on the link)");
    v("max_side_px", max_side_px, "a picture is reduced to at most this many pixels a side");
    v("jpeg_quality", jpeg_quality, "JPEG quality of the pictures, 1-100");
    v("min_view_change", min_view_change,
      "a keyframe's picture is sent when the camera moved by this share of its footprint (at the submap's scene depth) "
      "or turned by this share of the field of view since the last one sent in its submap");
  }
  bool Check(std::string* why) const;
};

// Decides, keyframe by keyframe, which pictures go to the ground. One owner; not thread-safe.
class KeyframeImagePicker {
 public:
  explicit KeyframeImagePicker(const KeyframeImageOptions& options) : options_(options) {}
  // Whether the keyframe of `submap` at `world_from_cam` (the submap's frame, whose unit is its scene
  // depth) should be sent; remembers it when so.
  bool Take(int64_t submap, const Rigid3d& world_from_cam, const Camera& camera);

 private:
  KeyframeImageOptions options_;
  std::optional<int64_t> submap_;
  Rigid3d last_sent_;
};

// The picture sent: `image` (CV_8UC1) reduced to at most max_side_px a side by area averaging and
// JPEG-compressed. Throws stitch::Error for an empty image.
std::vector<uint8_t> EncodeKeyframePicture(const cv::Mat& image, const KeyframeImageOptions& options, cv::Size* size);

}  // namespace stitch
