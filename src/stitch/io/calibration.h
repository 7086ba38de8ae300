#pragma once
// Calibration files. Reads, detecting the layout:
//  - ORB-SLAM2 / ORB-SLAM3 settings (Camera.fx ... or Camera1.fx ..., Camera.type), which many
//    users already have, read as they are with the parser ORB-SLAM uses (OpenCV's FileStorage:
//    `%YAML:1.0`, `key:value` without a space); this is also the layout stitch writes;
//  - EuRoC / Kalibr-style sensor.yaml (intrinsics, distortion_coefficients, resolution);
//  - KITTI odometry calib.txt (P0: 3x4 projection matrix; rectified, no distortion).

#include <map>
#include <optional>
#include <string>

#include "stitch/geometry/camera.h"

namespace stitch {

// Loads a camera. The image size comes from the file when it states one; otherwise from
// `image_width` x `image_height` (pass 0 to require the file to state it). When both are known
// and differ, throws stitch::Error saying so.
Camera LoadCalibration(const std::string& path, int image_width = 0, int image_height = 0);

// The feature extractor's settings an ORB-SLAM settings file states, by their ORB-SLAM names
// without the "ORBextractor." prefix (nFeatures, scaleFactor, nLevels, iniThFAST, minThFAST);
// empty for a file of another layout. Throws stitch::Error for a value that is no number.
std::map<std::string, double> ReadOrbExtractorSettings(const std::string& path);

// What looks wrong in a calibration for its images, as a sentence ("" when nothing): a principal
// point far from the image's centre (more than a fifth of its width or height away), as another
// camera's settings give (ORB-SLAM2's KITTI file, cx 607, on a 640-wide image).
std::string CalibrationDoubts(const Camera& camera);

// A rolling shutter's readout delay from one row to the next a calibration file states
// (`Camera.line_delay_us`, microseconds; stitch's key, which ORB-SLAM ignores); empty when it
// states none (or is no settings file). Throws stitch::Error for a value that is no number.
std::optional<double> ReadLineDelayUs(const std::string& path);

// Writes the camera as an ORB-SLAM-style settings file, with Camera.line_delay_us when a rolling
// shutter's `line_delay_us` is given.
void SaveCalibration(const Camera& camera, const std::string& path, double line_delay_us = 0);

}  // namespace stitch
