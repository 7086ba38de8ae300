#include "stitch/geometry/camera.h"

#include <cmath>
#include <sstream>

#include <Eigen/LU>

#include "stitch/util/error.h"

namespace stitch {

const char* CameraModelName(CameraModel model) {
  switch (model) {
    case CameraModel::kPinholeRadTan:
      return "pinhole-radtan";
    case CameraModel::kFisheye:
      return "fisheye";
  }
  return "unknown";
}

int Camera::NumParams(CameraModel model) {
  return model == CameraModel::kPinholeRadTan ? 9 : 8;
}

Camera::Camera(CameraModel model, int width, int height, const std::vector<double>& params)
    : model_(model), width_(width), height_(height) {
  if (static_cast<int>(params.size()) != NumParams(model)) {
    throw Error(Str() << CameraModelName(model) << " camera needs " << NumParams(model) << " parameters, got "
                      << params.size());
  }
  for (size_t i = 0; i < params.size(); ++i) params_[i] = params[i];
  std::string why;
  if (!Check(&why)) throw Error("invalid camera: " + why);
}

Camera Camera::Pinhole(int width, int height, double fx, double fy, double cx, double cy, double k1, double k2,
                       double p1, double p2, double k3) {
  return Camera(CameraModel::kPinholeRadTan, width, height, {fx, fy, cx, cy, k1, k2, p1, p2, k3});
}

std::vector<double> Camera::params() const {
  return std::vector<double>(params_.begin(), params_.begin() + NumParams(model_));
}

bool Camera::HasDistortion() const {
  for (int i = 4; i < NumParams(model_); ++i) {
    if (params_[i] != 0.0) return true;
  }
  return false;
}

Eigen::Vector2d Camera::Distort(const Eigen::Vector2d& u) const {
  const double x = u.x();
  const double y = u.y();
  if (model_ == CameraModel::kPinholeRadTan) {
    const double k1 = params_[4], k2 = params_[5], p1 = params_[6], p2 = params_[7], k3 = params_[8];
    const double r2 = x * x + y * y;
    const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
    return {x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y};
  }
  // Equidistant fisheye: theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8).
  const double r = std::sqrt(x * x + y * y);
  if (r < 1e-12) return u;
  const double theta = std::atan(r);
  const double t2 = theta * theta;
  const double theta_d = theta * (1.0 + t2 * (params_[4] + t2 * (params_[5] + t2 * (params_[6] + t2 * params_[7]))));
  return u * (theta_d / r);
}

Eigen::Vector2d Camera::NormalizedToPixel(const Eigen::Vector2d& normalized) const {
  const Eigen::Vector2d d = HasDistortion() ? Distort(normalized) : normalized;
  return {fx() * d.x() + cx(), fy() * d.y() + cy()};
}

std::optional<Eigen::Vector2d> Camera::Project(const Eigen::Vector3d& point_in_cam) const {
  if (point_in_cam.z() <= 0.0) return std::nullopt;
  return NormalizedToPixel(point_in_cam.head<2>() / point_in_cam.z());
}

Eigen::Vector2d Camera::PixelToNormalized(const Eigen::Vector2d& pixel) const {
  const Eigen::Vector2d distorted((pixel.x() - cx()) / fx(), (pixel.y() - cy()) / fy());
  if (!HasDistortion()) return distorted;
  if (model_ == CameraModel::kFisheye) {
    // Solve theta_d = f(theta) by Newton's method, then the ray is tan(theta) along distorted.
    const double theta_d = distorted.norm();
    if (theta_d < 1e-12) return distorted;
    double theta = theta_d;
    for (int i = 0; i < 20; ++i) {
      const double t2 = theta * theta;
      const double f =
          theta * (1 + t2 * (params_[4] + t2 * (params_[5] + t2 * (params_[6] + t2 * params_[7])))) - theta_d;
      const double df = 1 + t2 * (3 * params_[4] + t2 * (5 * params_[5] + t2 * (7 * params_[6] + t2 * 9 * params_[7])));
      const double step = f / df;
      theta -= step;
      if (std::abs(step) < 1e-14) break;
    }
    return distorted * (std::tan(theta) / theta_d);
  }
  // Radial-tangential: Gauss-Newton on Distort(u) = distorted with a numeric Jacobian, starting at
  // the distorted point. Converges in a few steps for every real lens inside the image.
  Eigen::Vector2d u = distorted;
  for (int i = 0; i < 30; ++i) {
    const Eigen::Vector2d residual = Distort(u) - distorted;
    if (residual.squaredNorm() < 1e-24) break;
    const double h = 1e-7;
    Eigen::Matrix2d jacobian;
    jacobian.col(0) = (Distort(u + Eigen::Vector2d(h, 0)) - Distort(u - Eigen::Vector2d(h, 0))) / (2 * h);
    jacobian.col(1) = (Distort(u + Eigen::Vector2d(0, h)) - Distort(u - Eigen::Vector2d(0, h))) / (2 * h);
    u -= jacobian.inverse() * residual;
  }
  return u;
}

Eigen::Vector3d Camera::PixelToRay(const Eigen::Vector2d& pixel) const {
  const Eigen::Vector2d n = PixelToNormalized(pixel);
  return Eigen::Vector3d(n.x(), n.y(), 1.0).normalized();
}

Eigen::Vector2d Camera::UndistortPixel(const Eigen::Vector2d& pixel) const {
  const Eigen::Vector2d n = PixelToNormalized(pixel);
  return {fx() * n.x() + cx(), fy() * n.y() + cy()};
}

Camera Camera::Resized(int width, int height) const {
  if (width <= 0 || height <= 0)
    throw Error("a camera resized to " + std::to_string(width) + "x" + std::to_string(height));
  const double sx = static_cast<double>(width) / width_, sy = static_cast<double>(height) / height_;
  Camera resized = *this;
  resized.width_ = width;
  resized.height_ = height;
  resized.params_[0] *= sx;
  resized.params_[1] *= sy;
  // Pixel centres: x_new + 0.5 = sx * (x_old + 0.5).
  resized.params_[2] = (cx() + 0.5) * sx - 0.5;
  resized.params_[3] = (cy() + 0.5) * sy - 0.5;
  return resized;
}

bool Camera::Check(std::string* why) const {
  auto fail = [&](const std::string& message) {
    if (why) *why = message;
    return false;
  };
  for (int i = 0; i < NumParams(model_); ++i) {
    if (!std::isfinite(params_[i])) return fail("a camera parameter is not a finite number");
  }
  if (width_ <= 0 || height_ <= 0) {
    return fail(Str() << "image size " << width_ << "x" << height_ << " is not positive");
  }
  if (fx() <= 0 || fy() <= 0) {
    return fail(Str() << "focal lengths fx=" << fx() << " fy=" << fy() << " must be positive");
  }
  if (fx() / fy() > 4 || fy() / fx() > 4) {
    return fail(Str() << "focal lengths fx=" << fx() << " fy=" << fy() << " differ by more than 4x");
  }
  if (cx() < 0 || cy() < 0 || cx() > width_ || cy() > height_) {
    return fail(Str() << "principal point (" << cx() << ", " << cy() << ") lies outside the " << width_ << "x"
                      << height_ << " image");
  }
  if (HasDistortion()) {
    // The distortion must be one-to-one over the image: along the ray to each image corner, the
    // distorted radius must grow with the undistorted one up to the corner, and undistorting the
    // corner must find that point (not one on a folded-over branch).
    const Eigen::Vector2d corners[] = {
        {-0.5, -0.5}, {width_ - 0.5, -0.5}, {-0.5, height_ - 0.5}, {width_ - 0.5, height_ - 0.5}};
    for (const auto& corner : corners) {
      const Eigen::Vector2d undistorted = PixelToNormalized(corner);
      const bool round_trip = undistorted.allFinite() && (NormalizedToPixel(undistorted) - corner).norm() < 0.01;
      bool monotonic = round_trip;
      double previous = 0.0;
      for (int step = 1; monotonic && step <= 200; ++step) {
        const double radius = Distort(undistorted * (step / 200.0)).norm();
        monotonic = radius > previous;
        previous = radius;
      }
      if (!monotonic) {
        return fail(Str() << "distortion parameters fold the image over itself towards corner (" << corner.x() << ", "
                          << corner.y() << "): check their order and values");
      }
    }
  }
  return true;
}

std::string Camera::Describe() const {
  std::ostringstream s;
  s << CameraModelName(model_) << " " << width_ << "x" << height_ << " fx=" << fx() << " fy=" << fy() << " cx=" << cx()
    << " cy=" << cy();
  if (HasDistortion()) {
    s << " dist=[";
    for (int i = 4; i < NumParams(model_); ++i) s << (i > 4 ? " " : "") << params_[i];
    s << "]";
  }
  return s.str();
}

}  // namespace stitch
