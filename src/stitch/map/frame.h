#pragma once
// A camera frame with its features, and the helpers that make features searchable: the scale
// pyramid's constants, an undistortion lookup, and a grid for area queries.

#include <atomic>
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "stitch/features/bow.h"
#include "stitch/features/orb_extractor.h"
#include "stitch/features/vocabulary.h"
#include "stitch/geometry/camera.h"
#include "stitch/geometry/rigid3.h"
#include "stitch/util/ids.h"

namespace stitch {

// Constants of the extractor's pyramid, shared by frames, keyframes and points.
struct ScalePyramid {
  int num_levels = 8;
  double scale_factor = 1.2;
  double log_scale_factor = 0;
  std::vector<float> scale;   // scale_factor^level
  std::vector<float> sigma2;  // scale^2: variance of a measurement at the level, px^2
  std::vector<float> inverse_sigma2;

  static ScalePyramid From(const OrbOptions& options);
  // The level a point at `distance` would be seen at, given its scale-invariance range.
  int PredictLevel(double distance, double max_distance) const;
};

// Maps distorted pixels to the ideal pinhole image (same fx, fy, cx, cy) through a per-pixel
// table, interpolated between pixels: fast for the thousand keypoints of every frame. The table is
// filled as keypoints need its pixels (each pixel's exact inverse, computed once), not all at
// construction: a whole 640x480 table took 60-90 ms, the tracker's first frame. A camera without
// distortion needs no table (16 MB at 1080p, 66 MB at 4K). Copies share the table; thread-safe.
class Undistorter {
 public:
  Undistorter() = default;
  explicit Undistorter(const Camera& camera);
  Eigen::Vector2d Undistort(double x, double y) const;
  // Bounds of the undistorted image (where undistorted keypoints can lie).
  double min_x() const { return min_x_; }
  double min_y() const { return min_y_; }
  double max_x() const { return max_x_; }
  double max_y() const { return max_y_; }
  const Camera& camera() const { return camera_; }
  // Pixels of the table filled so far (0 without distortion); for tests.
  int64_t pixels_filled() const;

 private:
  // The table entry of pixel (x, y), computed on first use.
  Eigen::Vector2f Pixel(int x, int y) const;

  Camera camera_;
  // Per pixel, the undistorted point's two floats packed in 64 bits; 0: not computed yet (a
  // point at exactly (0, 0) is computed each time). Relaxed atomics: every thread that computes
  // an entry writes the same value. Absent without distortion.
  std::shared_ptr<std::atomic<uint64_t>[]> table_;
  double min_x_ = 0, min_y_ = 0, max_x_ = 0, max_y_ = 0;
};

// Feature indices bucketed by undistorted position, for "features near (x, y)" queries.
class FeatureGrid {
 public:
  static constexpr int kCols = 64, kRows = 48;

  FeatureGrid() = default;
  FeatureGrid(const std::vector<Eigen::Vector2d>& points, const Undistorter& bounds);
  // Features within `radius` (px) of (x, y) whose level is in [min_level, max_level]
  // (max_level < 0: any level above min_level).
  std::vector<int> InArea(double x, double y, double radius, const std::vector<cv::KeyPoint>& keypoints,
                          const std::vector<Eigen::Vector2d>& points, int min_level = -1, int max_level = -1) const;

 private:
  // Features sorted by cell: cell k holds indices_[cell_start_[k], cell_start_[k + 1]) (two flat
  // arrays, about 16 kB for 1000 features, where a vector per cell took about 100 kB).
  std::vector<int> cell_start_;
  std::vector<int> indices_;
  double min_x_ = 0, min_y_ = 0, inv_cell_w_ = 0, inv_cell_h_ = 0;
};

// One image's features. Value type; a frame is owned by whoever tracks it.
struct Frame {
  int frame_index = -1;
  int64_t t_ns = 0;
  std::vector<cv::KeyPoint> keypoints;       // distorted image
  std::vector<Eigen::Vector2d> undistorted;  // ideal pinhole image
  cv::Mat descriptors;                       // N x 32
  BowVector bow;                             // empty until computed
  FeatureVector bow_features;
  FeatureGrid grid;
  std::vector<MapPointId> points;  // per feature; invalid when none
  std::vector<char> outlier;       // per feature
  std::optional<Rigid3d> cam_from_world;
  double sharpness = 0;  // ImageSharpness of the image

  size_t size() const { return keypoints.size(); }
  int CountTracked() const;  // features with a point that is not an outlier
};

// Mean absolute Laplacian of the half-size image: falls sharply when motion blurs the image.
double ImageSharpness(const cv::Mat& image);

// Orientation rounded to 1/256 turn, in [0, 360).
float QuantizeAngle(float degrees);

// The frame's bag of words and direct index (at the vocabulary's level), unless it has them.
void ComputeBow(const Vocabulary& vocabulary, Frame* frame);

// Extracts features from `image` and makes them searchable.
Frame MakeFrame(const cv::Mat& image, int frame_index, int64_t t_ns, OrbExtractor* extractor,
                const Undistorter& undistorter);

}  // namespace stitch
