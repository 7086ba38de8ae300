#include "stitch/mosaic/checkpoints.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "stitch/util/error.h"

namespace stitch {
namespace {

cv::Mat Grey(const cv::Mat& image) {
  if (image.channels() == 1) return image;
  cv::Mat grey;
  cv::cvtColor(image, grey, cv::COLOR_BGR2GRAY);
  return grey;
}

// The vertex of the parabola through (-1, a), (0, b), (1, c), as an offset from 0.
double ParabolaPeak(double a, double b, double c) {
  const double denominator = a - 2 * b + c;
  return std::abs(denominator) < 1e-12 ? 0.0 : std::clamp(0.5 * (a - c) / denominator, -0.5, 0.5);
}

}  // namespace

Similarity2d FitSimilarity2d(const std::vector<Eigen::Vector2d>& from, const std::vector<Eigen::Vector2d>& to) {
  if (from.size() != to.size() || from.size() < 2) throw Error("a 2D similarity needs at least two pairs of points");
  Eigen::Vector2d mean_from = Eigen::Vector2d::Zero(), mean_to = Eigen::Vector2d::Zero();
  for (size_t i = 0; i < from.size(); ++i) {
    mean_from += from[i];
    mean_to += to[i];
  }
  mean_from /= static_cast<double>(from.size());
  mean_to /= static_cast<double>(to.size());
  // As complex numbers: to - mean_to = (a + ib)(from - mean_from), a and b in least squares.
  double a = 0, b = 0, norm = 0;
  for (size_t i = 0; i < from.size(); ++i) {
    const Eigen::Vector2d p = from[i] - mean_from, q = to[i] - mean_to;
    a += p.dot(q);
    b += p.x() * q.y() - p.y() * q.x();
    norm += p.squaredNorm();
  }
  if (!(norm > 0)) throw Error("a 2D similarity of points all in one place");
  Similarity2d fit;
  fit.linear << a / norm, -b / norm, b / norm, a / norm;
  fit.shift = mean_to - fit.linear * mean_from;
  return fit;
}

CheckpointErrors MeasureCheckpoints(const cv::Mat& truth, const cv::Mat& mosaic, const cv::Mat& mask,
                                    const CheckpointOptions& options) {
  if (truth.size() != mosaic.size() || mask.size() != truth.size() || mask.type() != CV_8UC1) {
    throw Error("checkpoints need the truth, the mosaic and its mask on one grid");
  }
  CheckpointErrors errors;
  const cv::Mat truth_grey = Grey(truth), mosaic_grey = Grey(mosaic);
  const int half = options.patch_px / 2;
  const int reach = half + options.search_px + 1;
  // Checkpoints where the whole search window lies in the drawn mosaic.
  cv::Mat inside;
  cv::erode(mask > 0, inside, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * reach + 1, 2 * reach + 1)));
  std::vector<cv::Point2f> corners;
  if (cv::countNonZero(inside) == 0) return errors;
  cv::goodFeaturesToTrack(truth_grey, corners, options.max_checkpoints, 0.02, options.min_spacing_px, inside, 5);
  errors.candidates = static_cast<int>(corners.size());
  std::vector<Eigen::Vector2d> at, found;
  std::vector<double> distances;
  for (const cv::Point2f& corner : corners) {
    const int x = static_cast<int>(std::lround(corner.x)), y = static_cast<int>(std::lround(corner.y));
    const cv::Rect patch(x - half, y - half, 2 * half + 1, 2 * half + 1);
    const cv::Rect window(x - reach + 1, y - reach + 1, 2 * reach - 1, 2 * reach - 1);
    if ((patch & cv::Rect(0, 0, truth.cols, truth.rows)) != patch ||
        (window & cv::Rect(0, 0, truth.cols, truth.rows)) != window) {
      continue;
    }
    cv::Mat score;
    cv::matchTemplate(mosaic_grey(window), truth_grey(patch), score, cv::TM_CCOEFF_NORMED);
    double best = 0;
    cv::Point peak;
    cv::minMaxLoc(score, nullptr, &best, nullptr, &peak);
    // A peak on the window's edge may be a better one's slope outside it.
    if (best < options.min_correlation || peak.x == 0 || peak.y == 0 || peak.x == score.cols - 1 ||
        peak.y == score.rows - 1) {
      continue;
    }
    const double dx = ParabolaPeak(score.at<float>(peak.y, peak.x - 1), score.at<float>(peak.y, peak.x),
                                   score.at<float>(peak.y, peak.x + 1));
    const double dy = ParabolaPeak(score.at<float>(peak.y - 1, peak.x), score.at<float>(peak.y, peak.x),
                                   score.at<float>(peak.y + 1, peak.x));
    // The patch's centre sits at window.x + peak.x + half in the mosaic.
    const Eigen::Vector2d offset(window.x + peak.x + dx + half - x, window.y + peak.y + dy + half - y);
    at.emplace_back(x, y);
    found.push_back(at.back() + offset);
    errors.points.push_back({at.back(), offset, best});
    distances.push_back(offset.norm());
    errors.mean_offset_px += offset;
  }
  errors.checkpoints = static_cast<int>(at.size());
  if (at.empty()) return errors;
  errors.mean_offset_px /= static_cast<double>(at.size());
  double sum = 0;
  for (double d : distances) sum += d * d;
  errors.rms_px = std::sqrt(sum / distances.size());
  errors.max_px = *std::max_element(distances.begin(), distances.end());
  std::vector<double> sorted = distances;
  std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
  errors.median_px = sorted[sorted.size() / 2];
  if (at.size() >= 3) {
    const Similarity2d fit = FitSimilarity2d(at, found);
    errors.similarity_scale = fit.scale();
    errors.similarity_rotation_deg = fit.angle() * 180.0 / M_PI;
    double left = 0;
    for (size_t i = 0; i < at.size(); ++i) left += (fit * at[i] - found[i]).squaredNorm();
    errors.rms_after_similarity_px = std::sqrt(left / at.size());
  }
  return errors;
}

}  // namespace stitch
