#include "stitch/map/frame.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include <opencv2/imgproc.hpp>

namespace stitch {

ScalePyramid ScalePyramid::From(const OrbOptions& options) {
  ScalePyramid p;
  p.num_levels = options.num_levels;
  p.scale_factor = options.scale_factor;
  p.log_scale_factor = std::log(options.scale_factor);
  for (int i = 0; i < options.num_levels; ++i) {
    const float s = static_cast<float>(std::pow(options.scale_factor, i));
    p.scale.push_back(s);
    p.sigma2.push_back(s * s);
    p.inverse_sigma2.push_back(1.0f / (s * s));
  }
  return p;
}

int ScalePyramid::PredictLevel(double distance, double max_distance) const {
  const double ratio = max_distance / distance;
  const int level = static_cast<int>(std::ceil(std::log(ratio) / log_scale_factor));
  return std::clamp(level, 0, num_levels - 1);
}

Undistorter::Undistorter(const Camera& camera) : camera_(camera) {
  min_x_ = min_y_ = 0;
  max_x_ = camera.width() - 1;
  max_y_ = camera.height() - 1;
  if (!camera.HasDistortion()) return;
  const int64_t pixels = static_cast<int64_t>(camera.width()) * camera.height();
  // Value-initialized: all zero, "not computed"; the pages are the system's until touched.
  table_ = std::shared_ptr<std::atomic<uint64_t>[]>(new std::atomic<uint64_t>[pixels]());
  min_x_ = min_y_ = 1e18;
  max_x_ = max_y_ = -1e18;
  // The bounds from the border's pixels, unrounded.
  const auto bound = [&](int x, int y) {
    const Eigen::Vector2d u = camera.UndistortPixel(Eigen::Vector2d(x, y));
    min_x_ = std::min(min_x_, u.x());
    min_y_ = std::min(min_y_, u.y());
    max_x_ = std::max(max_x_, u.x());
    max_y_ = std::max(max_y_, u.y());
  };
  for (int x = 0; x < camera.width(); ++x) {
    bound(x, 0);
    bound(x, camera.height() - 1);
  }
  for (int y = 0; y < camera.height(); ++y) {
    bound(0, y);
    bound(camera.width() - 1, y);
  }
}

Eigen::Vector2f Undistorter::Pixel(int x, int y) const {
  std::atomic<uint64_t>& entry = table_[static_cast<int64_t>(y) * camera_.width() + x];
  uint64_t packed = entry.load(std::memory_order_relaxed);
  float xy[2];
  if (packed == 0) {
    const Eigen::Vector2d u = camera_.UndistortPixel(Eigen::Vector2d(x, y));
    xy[0] = static_cast<float>(u.x());
    xy[1] = static_cast<float>(u.y());
    std::memcpy(&packed, xy, sizeof(packed));
    entry.store(packed, std::memory_order_relaxed);
  } else {
    std::memcpy(xy, &packed, sizeof(packed));
  }
  return {xy[0], xy[1]};
}

int64_t Undistorter::pixels_filled() const {
  if (!table_) return 0;
  const int64_t pixels = static_cast<int64_t>(camera_.width()) * camera_.height();
  int64_t filled = 0;
  for (int64_t i = 0; i < pixels; ++i) filled += table_[i].load(std::memory_order_relaxed) != 0;
  return filled;
}

Eigen::Vector2d Undistorter::Undistort(double x, double y) const {
  if (!table_) return {x, y};
  // Bilinear interpolation of the table (the mapping is smooth at pixel scale).
  const double cx = std::clamp(x, 0.0, camera_.width() - 1.001);
  const double cy = std::clamp(y, 0.0, camera_.height() - 1.001);
  // Outside the table (never for keypoints) fall back to the exact inverse.
  if (cx != x || cy != y) return camera_.UndistortPixel(Eigen::Vector2d(x, y));
  const int x0 = static_cast<int>(cx), y0 = static_cast<int>(cy);
  const double fx = cx - x0, fy = cy - y0;
  const Eigen::Vector2f p00 = Pixel(x0, y0), p10 = Pixel(x0 + 1, y0);
  const Eigen::Vector2f p01 = Pixel(x0, y0 + 1), p11 = Pixel(x0 + 1, y0 + 1);
  const auto blend = [&](int i) {
    return (p00[i] * (1 - fx) + p10[i] * fx) * (1 - fy) + (p01[i] * (1 - fx) + p11[i] * fx) * fy;
  };
  return {blend(0), blend(1)};
}

FeatureGrid::FeatureGrid(const std::vector<Eigen::Vector2d>& points, const Undistorter& bounds)
    : cell_start_(kCols * kRows + 1, 0),
      min_x_(bounds.min_x()),
      min_y_(bounds.min_y()),
      inv_cell_w_(kCols / std::max(1e-9, bounds.max_x() - bounds.min_x())),
      inv_cell_h_(kRows / std::max(1e-9, bounds.max_y() - bounds.min_y())) {
  // Counting sort of the features by cell, in index order within a cell.
  std::vector<int> cell_of(points.size(), -1);
  for (size_t i = 0; i < points.size(); ++i) {
    const int cx = static_cast<int>(std::floor((points[i].x() - min_x_) * inv_cell_w_));
    const int cy = static_cast<int>(std::floor((points[i].y() - min_y_) * inv_cell_h_));
    if (cx < 0 || cy < 0 || cx >= kCols || cy >= kRows) continue;
    cell_of[i] = cy * kCols + cx;
    ++cell_start_[cell_of[i] + 1];
  }
  for (int k = 0; k < kCols * kRows; ++k) cell_start_[k + 1] += cell_start_[k];
  indices_.resize(cell_start_.back());
  std::vector<int> next(cell_start_.begin(), cell_start_.end() - 1);
  for (size_t i = 0; i < points.size(); ++i) {
    if (cell_of[i] >= 0) indices_[next[cell_of[i]]++] = static_cast<int>(i);
  }
}

std::vector<int> FeatureGrid::InArea(double x, double y, double radius, const std::vector<cv::KeyPoint>& keypoints,
                                     const std::vector<Eigen::Vector2d>& points, int min_level, int max_level) const {
  std::vector<int> found;
  if (cell_start_.empty()) return found;
  const int c0 = std::max(0, static_cast<int>(std::floor((x - radius - min_x_) * inv_cell_w_)));
  const int c1 = std::min(kCols - 1, static_cast<int>(std::floor((x + radius - min_x_) * inv_cell_w_)));
  const int r0 = std::max(0, static_cast<int>(std::floor((y - radius - min_y_) * inv_cell_h_)));
  const int r1 = std::min(kRows - 1, static_cast<int>(std::floor((y + radius - min_y_) * inv_cell_h_)));
  if (c0 > c1 || r0 > r1) return found;
  const bool check_levels = min_level > 0 || max_level >= 0;
  const double r2 = radius * radius;
  for (int r = r0; r <= r1; ++r) {
    for (int c = c0; c <= c1; ++c) {
      const int cell = r * kCols + c;
      for (int k = cell_start_[cell]; k < cell_start_[cell + 1]; ++k) {
        const int i = indices_[k];
        if (check_levels) {
          const int level = keypoints[i].octave;
          if (level < min_level) continue;
          if (max_level >= 0 && level > max_level) continue;
        }
        const double dx = points[i].x() - x, dy = points[i].y() - y;
        if (dx * dx + dy * dy <= r2) found.push_back(i);
      }
    }
  }
  return found;
}

double ImageSharpness(const cv::Mat& image) {
  cv::Mat half;
  cv::resize(image, half, cv::Size(), 0.5, 0.5, cv::INTER_AREA);
  const int w = half.cols, h = half.rows;
  if (w < 2 || h < 2) return 0;
  // The 4-neighbour Laplacian with reflected borders (cv::Laplacian, ksize 1, BORDER_REFLECT_101)
  // summed in one pass: the same figure as Laplacian, abs and mean, eight times faster.
  const auto reflect = [](int i, int n) { return i < 0 ? 1 : (i >= n ? n - 2 : i); };
  int64_t sum = 0;
  for (int y = 0; y < h; ++y) {
    const uint8_t* up = half.ptr<uint8_t>(reflect(y - 1, h));
    const uint8_t* row = half.ptr<uint8_t>(y);
    const uint8_t* down = half.ptr<uint8_t>(reflect(y + 1, h));
    int32_t line = std::abs(up[0] + down[0] + 2 * row[1] - 4 * row[0]);
    for (int x = 1; x < w - 1; ++x) line += std::abs(up[x] + down[x] + row[x - 1] + row[x + 1] - 4 * row[x]);
    line += std::abs(up[w - 1] + down[w - 1] + 2 * row[w - 2] - 4 * row[w - 1]);
    sum += line;
  }
  return static_cast<double>(sum) / (static_cast<double>(w) * h);
}

float QuantizeAngle(float degrees) {
  const int steps = static_cast<int>(std::lround(degrees * 256.0f / 360.0f)) & 255;
  return steps * 360.0f / 256.0f;
}

int Frame::CountTracked() const {
  int count = 0;
  for (size_t i = 0; i < points.size(); ++i) count += points[i].valid() && !outlier[i];
  return count;
}

Frame MakeFrame(const cv::Mat& image, int frame_index, int64_t t_ns, OrbExtractor* extractor,
                const Undistorter& undistorter) {
  Frame frame;
  frame.frame_index = frame_index;
  frame.t_ns = t_ns;
  frame.sharpness = ImageSharpness(image);
  extractor->Extract(image, &frame.keypoints, &frame.descriptors);
  // Positions in 1/8 pixel and orientations in 1/256 turn: what keyframe_t carries, so a keyframe
  // is the same in the tracker that made it and in every process that receives it.
  for (auto& k : frame.keypoints) {
    k.pt.x = std::round(k.pt.x * 8.0f) / 8.0f;
    k.pt.y = std::round(k.pt.y * 8.0f) / 8.0f;
    k.angle = QuantizeAngle(k.angle);
  }
  frame.undistorted.reserve(frame.keypoints.size());
  for (const auto& k : frame.keypoints) frame.undistorted.push_back(undistorter.Undistort(k.pt.x, k.pt.y));
  frame.grid = FeatureGrid(frame.undistorted, undistorter);
  frame.points.assign(frame.keypoints.size(), MapPointId());
  frame.outlier.assign(frame.keypoints.size(), 0);
  return frame;
}

void ComputeBow(const Vocabulary& vocabulary, Frame* frame) {
  if (frame->bow.empty()) frame->bow = vocabulary.Transform(frame->descriptors, &frame->bow_features);
}

}  // namespace stitch
