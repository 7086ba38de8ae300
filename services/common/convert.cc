#include "services/common/convert.h"

#include <optional>
#include <utility>

#include <opencv2/imgcodecs.hpp>

#include "stitch/mosaic/live_mosaic.h"
#include "stitch/tracking_status_t.hpp"
#include "stitch/util/error.h"

namespace stitch {

stitch::camera_t ToMessage(const Camera& camera) {
  stitch::camera_t message{};
  message.model = camera.model() == CameraModel::kPinholeRadTan ? stitch::camera_t::MODEL_PINHOLE_RADTAN
                                                                : stitch::camera_t::MODEL_FISHEYE;
  message.width = camera.width();
  message.height = camera.height();
  message.params = camera.params();
  message.num_params = static_cast<int8_t>(message.params.size());
  return message;
}

Camera FromMessage(const stitch::camera_t& message) {
  CameraModel model;
  if (message.model == stitch::camera_t::MODEL_PINHOLE_RADTAN) {
    model = CameraModel::kPinholeRadTan;
  } else if (message.model == stitch::camera_t::MODEL_FISHEYE) {
    model = CameraModel::kFisheye;
  } else {
    throw Error("camera message: unknown model " + std::to_string(message.model));
  }
  return Camera(model, message.width, message.height, message.params);
}

namespace {

void QuaternionToWxyz(const Eigen::Quaterniond& q, double* wxyz) {
  wxyz[0] = q.w();
  wxyz[1] = q.x();
  wxyz[2] = q.y();
  wxyz[3] = q.z();
}

// Throws stitch::Error for a quaternion far from unit length (a corrupt message).
Eigen::Quaterniond WxyzToQuaternion(const double* wxyz, const char* type) {
  const Eigen::Quaterniond q(wxyz[0], wxyz[1], wxyz[2], wxyz[3]);
  if (!(q.norm() > 0.5 && q.norm() < 1.5))
    throw Error(std::string(type) + " message: rotation is not a unit quaternion");
  return q.normalized();
}

// Throws stitch::Error for a translation with a non-finite component (a corrupt or forged message).
Eigen::Vector3d FiniteTranslation(const double* xyz, const char* type) {
  const Eigen::Vector3d t(xyz[0], xyz[1], xyz[2]);
  if (!t.allFinite()) throw Error(std::string(type) + " message: translation is not finite");
  return t;
}

}  // namespace

stitch::rigid3_t ToMessage(const Rigid3d& transform) {
  stitch::rigid3_t message;
  QuaternionToWxyz(transform.rotation, message.rotation_wxyz);
  for (int i = 0; i < 3; ++i) message.translation[i] = transform.translation[i];
  return message;
}

Rigid3d FromMessage(const stitch::rigid3_t& message) {
  return Rigid3d(WxyzToQuaternion(message.rotation_wxyz, "rigid3"), FiniteTranslation(message.translation, "rigid3"));
}

stitch::sim3_t ToMessage(const Sim3d& transform) {
  stitch::sim3_t message;
  message.scale = transform.scale;
  QuaternionToWxyz(transform.rotation, message.rotation_wxyz);
  for (int i = 0; i < 3; ++i) message.translation[i] = transform.translation[i];
  return message;
}

Sim3d FromMessage(const stitch::sim3_t& message) {
  if (!(message.scale > 0 && std::isfinite(message.scale))) throw Error("sim3 message: scale is not positive");
  return Sim3d(message.scale, WxyzToQuaternion(message.rotation_wxyz, "sim3"),
               FiniteTranslation(message.translation, "sim3"));
}

void ToFloatPose(const Rigid3d& transform, float* wxyz_xyz) {
  double wxyz[4];
  QuaternionToWxyz(transform.rotation, wxyz);
  for (int i = 0; i < 4; ++i) wxyz_xyz[i] = static_cast<float>(wxyz[i]);
  for (int i = 0; i < 3; ++i) wxyz_xyz[4 + i] = static_cast<float>(transform.translation[i]);
}

Rigid3d FromFloatPose(const float* wxyz_xyz, const char* what) {
  double values[7];
  for (int i = 0; i < 7; ++i) values[i] = wxyz_xyz[i];
  return Rigid3d(WxyzToQuaternion(values, what), FiniteTranslation(values + 4, what));
}

stitch::frame_pose_t FramePoseMessage(int frame_index, int64_t t_ns, SubmapId submap, const Rigid3d& cam_from_submap,
                                      KeyframeId reference, const std::optional<Rigid3d>& cam_from_reference) {
  stitch::frame_pose_t pose{};
  pose.frame_index = frame_index;
  pose.t_ns = t_ns;
  pose.submap_id = submap.value;
  const bool referenced = reference.valid() && cam_from_reference;
  pose.reference_keyframe = referenced ? reference.value : -1;
  ToFloatPose(referenced ? *cam_from_reference : Rigid3d(), pose.cam_from_reference);
  ToFloatPose(cam_from_submap, pose.cam_from_submap);
  return pose;
}

stitch::gnss_fix_t ToMessage(const GnssFix& fix) {
  stitch::gnss_fix_t message{};
  message.t_ns = fix.t_ns;
  message.latitude_deg = fix.position.latitude_deg;
  message.longitude_deg = fix.position.longitude_deg;
  message.height_m = fix.position.height_m;
  message.horizontal_accuracy_m = fix.horizontal_accuracy_m;
  message.vertical_accuracy_m = fix.vertical_accuracy_m;
  message.fix_type = static_cast<int8_t>(fix.type);
  return message;
}

GnssFix FromMessage(const stitch::gnss_fix_t& message) {
  static_assert(stitch::gnss_fix_t::FIX_NONE == static_cast<int>(GnssFixType::kNone) &&
                    stitch::gnss_fix_t::FIX_RTK_FIXED == static_cast<int>(GnssFixType::kRtkFixed),
                "the bus's fix types are the core's");
  if (message.fix_type < stitch::gnss_fix_t::FIX_NONE || message.fix_type > stitch::gnss_fix_t::FIX_RTK_FIXED) {
    throw Error("gnss_fix: unknown fix type " + std::to_string(message.fix_type));
  }
  if (message.t_ns < 0) throw Error("gnss_fix: negative time");
  GnssFix fix;
  fix.t_ns = message.t_ns;
  fix.position = {message.latitude_deg, message.longitude_deg, message.height_m};
  fix.horizontal_accuracy_m = message.horizontal_accuracy_m;
  fix.vertical_accuracy_m = message.vertical_accuracy_m;
  fix.type = static_cast<GnssFixType>(message.fix_type);
  if (const std::string why = WhyNotAFix(fix); !why.empty()) throw Error("gnss_fix: " + why);
  return fix;
}

ImageEncoding ParseImageEncoding(const std::string& name) {
  if (name == "gray8") return ImageEncoding::kGray8;
  if (name == "jpeg") return ImageEncoding::kJpeg;
  throw Error("image encoding '" + name + "' is not one of gray8, jpeg");
}

void EncodeImage(const cv::Mat& gray, ImageEncoding encoding, int jpeg_quality, stitch::frame_t* frame) {
  if (gray.type() != CV_8UC1) throw Error("EncodeImage: expected an 8-bit single-channel image");
  frame->width = gray.cols;
  frame->height = gray.rows;
  if (encoding == ImageEncoding::kGray8) {
    frame->encoding = stitch::frame_t::ENCODING_GRAY8;
    const cv::Mat continuous = gray.isContinuous() ? gray : gray.clone();
    frame->data.assign(continuous.data, continuous.data + continuous.total());
  } else {
    frame->encoding = stitch::frame_t::ENCODING_JPEG;
    if (!cv::imencode(".jpg", gray, frame->data, {cv::IMWRITE_JPEG_QUALITY, jpeg_quality})) {
      throw Error("EncodeImage: JPEG encoding failed");
    }
  }
  frame->num_bytes = static_cast<int32_t>(frame->data.size());
}

std::optional<std::pair<int, int>> JpegSize(const std::vector<uint8_t>& data) {
  const size_t n = data.size();
  if (n < 4 || data[0] != 0xFF || data[1] != 0xD8) return std::nullopt;
  size_t at = 2;
  while (at + 4 <= n) {
    if (data[at] != 0xFF) return std::nullopt;
    const uint8_t marker = data[at + 1];
    if (marker == 0xFF) {  // fill byte
      ++at;
      continue;
    }
    if (marker == 0x01 || (marker >= 0xD0 && marker <= 0xD7)) {  // no length
      at += 2;
      continue;
    }
    if (marker == 0xD9 || marker == 0xDA) return std::nullopt;  // end, or scan data before any frame header
    const size_t length = (static_cast<size_t>(data[at + 2]) << 8) | data[at + 3];
    if (length < 2 || at + 2 + length > n) return std::nullopt;
    const bool frame_header = marker >= 0xC0 && marker <= 0xCF && marker != 0xC4 && marker != 0xC8 && marker != 0xCC;
    if (frame_header) {
      if (length < 7) return std::nullopt;
      const int height = (data[at + 5] << 8) | data[at + 6], width = (data[at + 7] << 8) | data[at + 8];
      return std::make_pair(width, height);
    }
    at += 2 + length;
  }
  return std::nullopt;
}

cv::Mat DecodeImage(const stitch::frame_t& frame) {
  if (frame.width <= 0 || frame.height <= 0 || frame.width > 16384 || frame.height > 16384) {
    throw Error("frame " + std::to_string(frame.frame_index) + ": image size " + std::to_string(frame.width) + "x" +
                std::to_string(frame.height) + " is not plausible");
  }
  if (frame.encoding == stitch::frame_t::ENCODING_GRAY8) {
    const int64_t expected = static_cast<int64_t>(frame.width) * frame.height;
    if (static_cast<int64_t>(frame.data.size()) != expected) {
      throw Error("frame " + std::to_string(frame.frame_index) + ": " + std::to_string(frame.data.size()) +
                  " bytes for a " + std::to_string(frame.width) + "x" + std::to_string(frame.height) +
                  " gray8 image (expected " + std::to_string(expected) + ")");
    }
    return cv::Mat(frame.height, frame.width, CV_8UC1, const_cast<uint8_t*>(frame.data.data())).clone();
  }
  if (frame.encoding == stitch::frame_t::ENCODING_JPEG) {
    // The size its header claims, before anything is decoded: a few hundred bytes may claim
    // 32000x32000 (a gigabyte decoded).
    const std::optional<std::pair<int, int>> size = JpegSize(frame.data);
    if (!size) throw Error("frame " + std::to_string(frame.frame_index) + ": JPEG data names no image size");
    if (size->first != frame.width || size->second != frame.height) {
      throw Error("frame " + std::to_string(frame.frame_index) + ": JPEG header says " + std::to_string(size->first) +
                  "x" + std::to_string(size->second) + " but the frame says " + std::to_string(frame.width) + "x" +
                  std::to_string(frame.height) + "; not decoded");
    }
    cv::Mat image;
    try {
      image = cv::imdecode(frame.data, cv::IMREAD_GRAYSCALE);
    } catch (const cv::Exception&) {
      image.release();
    }
    if (image.empty()) throw Error("frame " + std::to_string(frame.frame_index) + ": JPEG data does not decode");
    if (image.cols != frame.width || image.rows != frame.height) {
      throw Error("frame " + std::to_string(frame.frame_index) + ": JPEG is " + std::to_string(image.cols) + "x" +
                  std::to_string(image.rows) + " but the frame says " + std::to_string(frame.width) + "x" +
                  std::to_string(frame.height));
    }
    return image;
  }
  throw Error("frame " + std::to_string(frame.frame_index) + ": unknown encoding " + std::to_string(frame.encoding));
}

KeyframePicture FromMessage(const stitch::keyframe_image_t& message) {
  const std::string what = "keyframe picture of frame " + std::to_string(message.frame_index);
  constexpr int kMaxSide = 8192;
  constexpr size_t kMaxBytes = 8u << 20;
  if (message.width <= 0 || message.height <= 0 || message.width > kMaxSide || message.height > kMaxSide ||
      message.camera_width < message.width || message.camera_height < message.height ||
      message.camera_width > 2 * kMaxSide || message.camera_height > 2 * kMaxSide) {
    throw Error(what + ": sizes " + std::to_string(message.width) + "x" + std::to_string(message.height) + " of a " +
                std::to_string(message.camera_width) + "x" + std::to_string(message.camera_height) +
                " camera are not plausible");
  }
  if (message.jpeg.size() > kMaxBytes) throw Error(what + ": " + std::to_string(message.jpeg.size()) + " bytes");
  const std::optional<std::pair<int, int>> size = JpegSize(message.jpeg);
  if (!size || size->first != message.width || size->second != message.height) {
    throw Error(what + ": its JPEG does not name the " + std::to_string(message.width) + "x" +
                std::to_string(message.height) + " it claims");
  }
  const SubmapId submap(message.submap_id);
  if (message.frame_index < 0 || !submap.valid() || SubmapOf(KeyframeId(message.keyframe_id)) != submap) {
    throw Error(what + ": names no keyframe of its submap");
  }
  KeyframePicture picture;
  picture.agent = AgentNumber(submap);
  picture.frame_index = message.frame_index;
  picture.t_ns = message.t_ns;
  picture.sent_utime = message.header.utime;
  picture.submap_id = message.submap_id;
  picture.keyframe_id = message.keyframe_id;
  picture.camera_width = message.camera_width;
  picture.camera_height = message.camera_height;
  picture.width = message.width;
  picture.height = message.height;
  picture.jpeg = message.jpeg;
  return picture;
}

stitch::mosaic_tile_t ToMessage(const LiveMosaicTile& tile, int64_t newest_picture_utime) {
  stitch::mosaic_tile_t message{};
  message.revision = tile.revision;
  message.frame_submap = tile.frame;
  message.ground_from_map = ToMessage(tile.ground_from_map);
  message.origin_x = tile.grid.origin.x();
  message.origin_y = tile.grid.origin.y();
  message.gsd = tile.grid.gsd;
  message.tile_px = tile.tile_px;
  message.col = tile.col;
  message.row = tile.row;
  message.version = tile.version;
  message.newest_picture_utime = newest_picture_utime;
  message.png = tile.png;
  message.num_bytes = static_cast<int32_t>(message.png.size());
  return message;
}

stitch::submap_request_t ToMessage(const DeliveryRequest& request) {
  stitch::submap_request_t m{};
  m.submap_id = request.submap.value;
  m.full_state = request.full_state;
  m.complete = request.complete;
  for (KeyframeId id : request.keyframes) m.keyframe_ids.push_back(id.value);
  m.num_keyframes = static_cast<int32_t>(m.keyframe_ids.size());
  return m;
}

DeliveryRequest FromMessage(const stitch::submap_request_t& message) {
  DeliveryRequest request;
  request.submap = SubmapId(message.submap_id);
  request.full_state = message.full_state;
  request.complete = message.complete;
  for (int64_t id : message.keyframe_ids) request.keyframes.push_back(KeyframeId(id));
  return request;
}

const char* MessageStateName(int8_t state) {
  switch (state) {
    case stitch::tracking_status_t::STATE_INITIALIZING:
      return "INITIALIZING";
    case stitch::tracking_status_t::STATE_OK:
      return "OK";
    case stitch::tracking_status_t::STATE_LOST:
      return "LOST";
    case stitch::tracking_status_t::STATE_SKIPPED:
      return "SKIPPED";
    case stitch::tracking_status_t::STATE_NOT_TRACKED:
      return "NOT_TRACKED";
    default:
      return "UNKNOWN";
  }
}

}  // namespace stitch
