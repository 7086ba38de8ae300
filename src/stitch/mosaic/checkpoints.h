#pragma once
// How far a mosaic's pixels are from where the truth has them: checkpoints (corners of the true
// orthophoto's texture) found again in the mosaic by normalized cross-correlation, on one grid.

#include <cmath>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace stitch {

struct CheckpointOptions {
  int patch_px = 21;             // the truth's patch around a checkpoint, a side
  int search_px = 16;            // how far from its place in the truth it is looked for in the mosaic
  double min_correlation = 0.8;  // a weaker best match is not a checkpoint
  int max_checkpoints = 2000;
  int min_spacing_px = 24;  // between checkpoints
};

struct CheckpointErrors {
  int candidates = 0;   // corners of the truth inside the mosaic
  int checkpoints = 0;  // found again in the mosaic
  // Each checkpoint's offset (mosaic minus truth), pixels.
  double rms_px = 0.0, median_px = 0.0, max_px = 0.0;
  Eigen::Vector2d mean_offset_px = Eigen::Vector2d::Zero();
  // After the 2D similarity (shift, rotation, scale) that fits the offsets best: what is left of
  // the mosaic's shape once its placement is taken out.
  double rms_after_similarity_px = 0.0;
  double similarity_scale = 1.0, similarity_rotation_deg = 0.0;
  // Each checkpoint: where it is in the truth and its offset, pixels.
  struct Checkpoint {
    Eigen::Vector2d at = Eigen::Vector2d::Zero();
    Eigen::Vector2d offset = Eigen::Vector2d::Zero();
    double correlation = 0.0;
  };
  std::vector<Checkpoint> points;
};

// The 2D similarity (scale, rotation, shift) taking `from` onto `to` in least squares: to ~=
// linear * from + shift. Throws stitch::Error for fewer than 2 pairs or points all in one place.
struct Similarity2d {
  Eigen::Matrix2d linear = Eigen::Matrix2d::Identity();  // scale times rotation
  Eigen::Vector2d shift = Eigen::Vector2d::Zero();
  double scale() const { return std::sqrt(std::abs(linear.determinant())); }
  double angle() const { return std::atan2(linear(1, 0), linear(0, 0)); }  // radians
  Eigen::Vector2d operator*(const Eigen::Vector2d& p) const { return linear * p + shift; }
};
Similarity2d FitSimilarity2d(const std::vector<Eigen::Vector2d>& from, const std::vector<Eigen::Vector2d>& to);

// `truth` and `mosaic` on the same grid (CV_8UC1 or CV_8UC3); `mask` (CV_8UC1, of their size)
// non-zero where the mosaic is drawn. Throws stitch::Error for images that differ in size.
CheckpointErrors MeasureCheckpoints(const cv::Mat& truth, const cv::Mat& mosaic, const cv::Mat& mask,
                                    const CheckpointOptions& options = {});

}  // namespace stitch
