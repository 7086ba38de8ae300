#pragma once
// A sparse model in COLMAP's text format (colmap.github.io/format.html): cameras.txt, images.txt
// and points3D.txt, which COLMAP, OpenMVS and most photogrammetry tools read. Cameras (one per
// calibration: several aircraft may fly different ones); images with their camera, their poses
// (cam_from_world) and 2D features; points with their tracks.
//
// Pixel convention: COLMAP puts the centre of the first pixel at (0.5, 0.5), OpenCV and stitch at
// (0, 0). The model here is in stitch's convention; the files in COLMAP's (written +0.5, read -0.5).

#include <array>
#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "stitch/geometry/camera.h"
#include "stitch/geometry/rigid3.h"

namespace stitch {

// COLMAP's first pixel centre, in stitch's pixels.
inline constexpr double kColmapHalfPixel = 0.5;

struct ColmapImage {
  int id = 0;         // from 1
  int camera_id = 1;  // its camera in ColmapModel::cameras
  Rigid3d cam_from_world;
  std::string name;                       // the image file, relative to the image folder COLMAP is given
  std::vector<Eigen::Vector2d> features;  // pixels, stitch's convention
  std::vector<int64_t> point_ids;         // per feature: its point, or -1
};

struct ColmapPoint {
  int64_t id = 0;  // from 1
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  std::array<uint8_t, 3> rgb{128, 128, 128};
  double error_px = 0;                     // mean reprojection error
  std::vector<std::pair<int, int>> track;  // (image id, feature index)
};

struct ColmapModel {
  std::map<int, Camera> cameras;  // by camera id (from 1)
  std::vector<ColmapImage> images;
  std::vector<ColmapPoint> points;
};

// COLMAP's name for the camera's model (PINHOLE, OPENCV, FULL_OPENCV, OPENCV_FISHEYE) and its
// parameters in COLMAP's order and pixel convention.
struct ColmapCameraModel {
  std::string name;  // PINHOLE, OPENCV, FULL_OPENCV or OPENCV_FISHEYE
  int id = 0;        // COLMAP's number of that model (its database's cameras.model)
  std::vector<double> params;
};
ColmapCameraModel ColmapCameraModelOf(const Camera& camera);
// The camera's line of cameras.txt.
std::string ColmapCameraLine(const Camera& camera, int id = 1);

// Writes DIR/cameras.txt, images.txt and points3D.txt (DIR is created). Throws stitch::Error.
void WriteColmapModel(const ColmapModel& model, const std::string& dir);
// Reads them back. Throws stitch::Error naming the file and line on anything malformed, a track
// naming an image or feature that is not there, an image naming a camera that is not there, or a
// camera model stitch does not know.
ColmapModel ReadColmapModel(const std::string& dir);

// The model for camera `camera_id`'s images resized to `width` x `height` (Camera::Resized): each
// of their features moves with its pixel, the reprojection errors are the new size's. A run that
// worked at a reduced size (ingest.max_working_pixels) goes back to its images' size this way.
ColmapModel ResizeColmapModel(ColmapModel model, int camera_id, int width, int height);

// Root mean square of every track's reprojection error, pixels (0 without observations).
double ReprojectionRms(const ColmapModel& model);
// Sets each point's error_px: the mean reprojection error of its track.
void SetReprojectionErrors(ColmapModel* model);

}  // namespace stitch
