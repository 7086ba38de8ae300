#pragma once
// Translation between core types and LCM messages. The SLAM core never sees LCM types.

#include <optional>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "stitch/camera_t.hpp"
#include "stitch/delivery/delivery.h"
#include "stitch/frame_pose_t.hpp"
#include "stitch/frame_t.hpp"
#include "stitch/geo/gnss_fix.h"
#include "stitch/geometry/camera.h"
#include "stitch/geometry/rigid3.h"
#include "stitch/gnss_fix_t.hpp"
#include "stitch/keyframe_image_t.hpp"
#include "stitch/mosaic_tile_t.hpp"
#include "stitch/records/keyframe_pictures.h"
#include "stitch/rigid3_t.hpp"
#include "stitch/sim3_t.hpp"
#include "stitch/submap_request_t.hpp"
#include "stitch/util/ids.h"

namespace stitch {

struct LiveMosaicTile;  // stitch/mosaic/live_mosaic.h

stitch::camera_t ToMessage(const Camera& camera);
// Throws stitch::Error when the message does not describe a usable camera.
Camera FromMessage(const stitch::camera_t& message);

stitch::rigid3_t ToMessage(const Rigid3d& transform);
Rigid3d FromMessage(const stitch::rigid3_t& message);
stitch::sim3_t ToMessage(const Sim3d& transform);
Sim3d FromMessage(const stitch::sim3_t& message);
// A pose as 7 floats (frame_pose_t): unit quaternion w, x, y, z, then translation. The reader
// throws stitch::Error for a rotation far from unit length or a translation that is not finite.
void ToFloatPose(const Rigid3d& transform, float* wxyz_xyz);
Rigid3d FromFloatPose(const float* wxyz_xyz, const char* what);
// A frame tracked OK as the pose stream carries it (<agent>/POSE); `reference` invalid or no
// `cam_from_reference`: tracked against no keyframe.
stitch::frame_pose_t FramePoseMessage(int frame_index, int64_t t_ns, SubmapId submap, const Rigid3d& cam_from_submap,
                                      KeyframeId reference, const std::optional<Rigid3d>& cam_from_reference);

// A GNSS fix on the bus (<agent>/GNSS). The reader throws stitch::Error for a fix type it does
// not know, or a fix that is no place on Earth or states no accuracy (WhyNotAFix).
stitch::gnss_fix_t ToMessage(const GnssFix& fix);
GnssFix FromMessage(const stitch::gnss_fix_t& message);

// A keyframe's picture for the ground (<agent>/KEYFRAME_IMAGE), checked before it is kept: a JPEG
// whose header names the size the message states (read without decoding), at most 8192 pixels a
// side and 8 MB, no larger than its camera's image, of a keyframe of the submap it names. Throws
// stitch::Error saying what is wrong. The agent is the submap's.
KeyframePicture FromMessage(const stitch::keyframe_image_t& message);

// The name of a tracking state on the bus (tracking_status_t::STATE_*), as TrackingStateName
// says it in the core ("UNKNOWN" for a value no tracker sends). Not the core's function: this
// library links no algorithm (a test holds the two to the same names).
const char* MessageStateName(int8_t state);

// The merger's requests to a mapper (<agent>/SUBMAP_REQUEST). The reader takes ids as they come
// (the sender finds no submap or keyframe for one not its own).
stitch::submap_request_t ToMessage(const DeliveryRequest& request);
// A live mosaic tile for the viewer; `newest_picture_utime`: MergeSession::MosaicTiles's.
stitch::mosaic_tile_t ToMessage(const LiveMosaicTile& tile, int64_t newest_picture_utime);
DeliveryRequest FromMessage(const stitch::submap_request_t& message);

enum class ImageEncoding { kGray8, kJpeg };
// Parses "gray8" or "jpeg"; throws stitch::Error otherwise.
ImageEncoding ParseImageEncoding(const std::string& name);

// Fills encoding, width, height and data of `frame` from a CV_8UC1 image.
void EncodeImage(const cv::Mat& gray, ImageEncoding encoding, int jpeg_quality, stitch::frame_t* frame);
// The frame's image as CV_8UC1. Throws stitch::Error saying what is wrong with a frame whose
// bytes do not make the image it claims (size mismatch, undecodable JPEG, unknown encoding).
cv::Mat DecodeImage(const stitch::frame_t& frame);
// The (width, height) a JPEG's frame header (SOFn) claims, read without decoding; nullopt when
// the bytes hold no frame header before the scan data.
std::optional<std::pair<int, int>> JpegSize(const std::vector<uint8_t>& data);

}  // namespace stitch
