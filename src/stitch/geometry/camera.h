#pragma once
// Camera models. Pixel convention: the centre of the top-left pixel is (0, 0), as in OpenCV.
// A Camera is a small value type; copy it freely. Thread-safe for concurrent const use.

#include <array>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace stitch {

// The ideal pinhole camera (no distortion): what undistorted keypoints live in.
struct PinholeIntrinsics {
  double fx = 1, fy = 1, cx = 0, cy = 0;
  Eigen::Vector2d Project(const Eigen::Vector3d& point_in_cam) const {
    return {fx * point_in_cam.x() / point_in_cam.z() + cx, fy * point_in_cam.y() / point_in_cam.z() + cy};
  }
  // Normalized image coordinates (x/z, y/z) of a pixel.
  Eigen::Vector2d Normalize(const Eigen::Vector2d& pixel) const {
    return {(pixel.x() - cx) / fx, (pixel.y() - cy) / fy};
  }
  Eigen::Matrix3d K() const {
    Eigen::Matrix3d k;
    k << fx, 0, cx, 0, fy, cy, 0, 0, 1;
    return k;
  }
};

enum class CameraModel {
  // fx fy cx cy k1 k2 p1 p2 k3: OpenCV's radial-tangential (plumb bob) model.
  kPinholeRadTan = 0,
  // fx fy cx cy k1 k2 k3 k4: equidistant fisheye, as cv::fisheye.
  kFisheye = 1,
};

const char* CameraModelName(CameraModel model);

class Camera {
 public:
  static constexpr int kMaxParams = 9;

  Camera() = default;
  // Throws stitch::Error if the parameters are not a usable camera (see Check).
  Camera(CameraModel model, int width, int height, const std::vector<double>& params);
  static Camera Pinhole(int width, int height, double fx, double fy, double cx, double cy, double k1 = 0, double k2 = 0,
                        double p1 = 0, double p2 = 0, double k3 = 0);

  CameraModel model() const { return model_; }
  int width() const { return width_; }
  int height() const { return height_; }
  double fx() const { return params_[0]; }
  double fy() const { return params_[1]; }
  double cx() const { return params_[2]; }
  double cy() const { return params_[3]; }
  PinholeIntrinsics Intrinsics() const { return {fx(), fy(), cx(), cy()}; }
  // All parameters in the model's order (size NumParams(model)).
  std::vector<double> params() const;
  static int NumParams(CameraModel model);
  bool HasDistortion() const;

  // Pixel of a point in camera coordinates; empty when the point is behind the camera (z <= 0).
  std::optional<Eigen::Vector2d> Project(const Eigen::Vector3d& point_in_cam) const;
  // Normalized image coordinates (x/z, y/z) -> pixel, through the distortion.
  Eigen::Vector2d NormalizedToPixel(const Eigen::Vector2d& normalized) const;
  // Pixel -> normalized image coordinates, inverting the distortion iteratively.
  Eigen::Vector2d PixelToNormalized(const Eigen::Vector2d& pixel) const;
  // Unit ray through a pixel, camera coordinates.
  Eigen::Vector3d PixelToRay(const Eigen::Vector2d& pixel) const;
  // Pixel in the ideal pinhole image with the same fx, fy, cx, cy (distortion removed).
  Eigen::Vector2d UndistortPixel(const Eigen::Vector2d& pixel) const;

  bool InImage(const Eigen::Vector2d& pixel, double border = 0.0) const {
    return pixel.x() >= border - 0.5 && pixel.y() >= border - 0.5 && pixel.x() <= width_ - 0.5 - border &&
           pixel.y() <= height_ - 0.5 - border;
  }
  // The same camera for its image resized to `width` x `height` (each axis by its own factor;
  // pixel centres scale about the image's corner at (-0.5, -0.5)). Distortion acts on normalized
  // coordinates and stays as it is.
  Camera Resized(int width, int height) const;
  // Returns false and says why if the camera cannot be used (non-positive focal length, principal
  // point far outside the image, non-invertible distortion inside the image...).
  bool Check(std::string* why) const;
  std::string Describe() const;

 private:
  Eigen::Vector2d Distort(const Eigen::Vector2d& undistorted) const;

  CameraModel model_ = CameraModel::kPinholeRadTan;
  int width_ = 0;
  int height_ = 0;
  std::array<double, kMaxParams> params_{};
};

}  // namespace stitch
