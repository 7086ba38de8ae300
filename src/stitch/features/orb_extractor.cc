#include "stitch/features/orb_extractor.h"

#include <algorithm>
#include <cmath>
#include <list>

#include <opencv2/imgproc.hpp>

#include "stitch/util/error.h"
#include "stitch/util/parallel.h"

namespace stitch {
namespace {

constexpr int kPatchSize = 31;      // ORB's descriptor patch
constexpr int kHalfPatchSize = 15;  // orientation patch radius
constexpr int kEdgeThreshold = 19;  // no keypoint closer to a level's border than this

struct QuadNode {
  cv::Point2f top_left, bottom_right;
  std::vector<cv::KeyPoint> points;
  bool Splittable() const {
    return points.size() > 1 && bottom_right.x - top_left.x > 1 && bottom_right.y - top_left.y > 1;
  }
  void Split(std::array<QuadNode, 4>* children) const {
    const cv::Point2f middle = (top_left + bottom_right) * 0.5f;
    (*children)[0].top_left = top_left;
    (*children)[0].bottom_right = middle;
    (*children)[1].top_left = {middle.x, top_left.y};
    (*children)[1].bottom_right = {bottom_right.x, middle.y};
    (*children)[2].top_left = {top_left.x, middle.y};
    (*children)[2].bottom_right = {middle.x, bottom_right.y};
    (*children)[3].top_left = middle;
    (*children)[3].bottom_right = bottom_right;
    for (auto& child : *children) child.points.clear();
    for (const auto& p : points) {
      const int index = (p.pt.x >= middle.x ? 1 : 0) + (p.pt.y >= middle.y ? 2 : 0);
      (*children)[index].points.push_back(p);
    }
  }
};

}  // namespace

bool OrbOptions::Check(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (num_features < 10 || num_features > 100000) return fail("orb.num_features must be in [10, 100000]");
  if (!(scale_factor > 1.0 && scale_factor <= 2.0)) return fail("orb.scale_factor must be in (1, 2]");
  if (num_levels < 1 || num_levels > 16) return fail("orb.num_levels must be in [1, 16]");
  if (min_fast_threshold < 1 || min_fast_threshold > fast_threshold || fast_threshold > 200) {
    return fail("orb: need 1 <= min_fast_threshold <= fast_threshold <= 200");
  }
  if (cell_size < 10 || cell_size > 500) return fail("orb.cell_size must be in [10, 500]");
  if (detector != "stitch" && detector != "opencv") return fail("orb.detector must be stitch or opencv");
  if (threads < 1 || threads > 16) return fail("orb.threads must be in [1, 16]");
  return true;
}

OrbExtractor::OrbExtractor(const OrbOptions& options) : options_(options) {
  std::string why;
  if (!options_.Check(&why)) throw Error(why);
  const int levels = options_.num_levels;
  scale_factors_.resize(levels);
  level_sigma2_.resize(levels);
  inverse_level_sigma2_.resize(levels);
  for (int i = 0; i < levels; ++i) {
    scale_factors_[i] = static_cast<float>(std::pow(options_.scale_factor, i));
    level_sigma2_[i] = scale_factors_[i] * scale_factors_[i];
    inverse_level_sigma2_[i] = 1.0f / level_sigma2_[i];
  }
  // Features per level fall geometrically with the level's linear size.
  const double factor = 1.0 / options_.scale_factor;
  double per_level = options_.num_features * (1 - factor) / (1 - std::pow(factor, levels));
  features_per_level_.resize(levels);
  int assigned = 0;
  for (int i = 0; i < levels - 1; ++i) {
    features_per_level_[i] = static_cast<int>(std::lround(per_level));
    assigned += features_per_level_[i];
    per_level *= factor;
  }
  features_per_level_[levels - 1] = std::max(options_.num_features - assigned, 0);
  // Row extents of a disc of radius 15, for the intensity centroid.
  circle_extent_.resize(kHalfPatchSize + 1);
  for (int v = 0; v <= kHalfPatchSize; ++v) {
    circle_extent_[v] = static_cast<int>(std::floor(std::sqrt(kHalfPatchSize * kHalfPatchSize - v * v + 0.5)));
  }
  runner_ = std::make_unique<ParallelRunner>(options_.threads);
  describer_ = cv::ORB::create(options_.num_features, static_cast<float>(options_.scale_factor), levels, kEdgeThreshold,
                               0, 2, cv::ORB::FAST_SCORE, kPatchSize, options_.fast_threshold);
}

OrbExtractor::~OrbExtractor() = default;
OrbExtractor::OrbExtractor(OrbExtractor&&) noexcept = default;

void OrbExtractor::BuildPyramid(const cv::Mat& image) {
  pyramid_.resize(options_.num_levels);
  pyramid_[0] = image;
  for (int level = 1; level < options_.num_levels; ++level) {
    const cv::Size size(cvRound(image.cols / scale_factors_[level]), cvRound(image.rows / scale_factors_[level]));
    cv::resize(pyramid_[level - 1], pyramid_[level], size, 0, 0, cv::INTER_LINEAR);
  }
}

std::vector<cv::KeyPoint> OrbExtractor::DetectLevel(int level) const {
  const cv::Mat& image = pyramid_[level];
  const cv::Rect area(kEdgeThreshold - 3, kEdgeThreshold - 3, image.cols - 2 * (kEdgeThreshold - 3),
                      image.rows - 2 * (kEdgeThreshold - 3));
  if (area.width <= 6 || area.height <= 6) return {};
  // FAST at the preferred threshold over the level; then, in each cell without such a corner,
  // FAST again at the low threshold (strong corners where there are some, weak ones elsewhere).
  // Same corners as one low-threshold pass filtered per cell, at a fraction of its cost: a low
  // threshold fires on most pixels of a textured image.
  const int cells_x = std::max(1, area.width / options_.cell_size);
  const int cells_y = std::max(1, area.height / options_.cell_size);
  const float cell_w = static_cast<float>(area.width) / cells_x, cell_h = static_cast<float>(area.height) / cells_y;
  const auto cell_of = [&](const cv::Point2f& p) {
    const int cx = std::min(cells_x - 1, static_cast<int>(p.x / cell_w));
    const int cy = std::min(cells_y - 1, static_cast<int>(p.y / cell_h));
    return cy * cells_x + cx;
  };
  // FAST cannot fire within 3 pixels of the area's border; no keypoint within the edge margin.
  const auto inside = [&](const cv::Point2f& p) {
    return p.x >= 3 && p.y >= 3 && p.x < area.width - 3 && p.y < area.height - 3;
  };
  std::vector<cv::KeyPoint> corners, kept;
  cv::FAST(image(area), corners, options_.fast_threshold, true);
  std::vector<char> cell_has_strong(cells_x * cells_y, 0);
  kept.reserve(corners.size());
  for (const auto& k : corners) {
    if (!inside(k.pt)) continue;
    cell_has_strong[cell_of(k.pt)] = 1;
    kept.push_back(k);
  }
  std::vector<cv::KeyPoint> weak;
  for (int cy = 0; cy < cells_y; ++cy) {
    for (int cx = 0; cx < cells_x; ++cx) {
      const int cell = cy * cells_x + cx;
      if (cell_has_strong[cell]) continue;
      // The cell and 4 pixels around it: FAST's 3-pixel ring and the neighbours its non-maximum
      // suppression compares, so the cell's corners are those of a pass over the whole level.
      const int x0 = std::max(0, static_cast<int>(cx * cell_w) - 4),
                y0 = std::max(0, static_cast<int>(cy * cell_h) - 4);
      const int x1 = std::min(area.width, static_cast<int>((cx + 1) * cell_w) + 5);
      const int y1 = std::min(area.height, static_cast<int>((cy + 1) * cell_h) + 5);
      cv::FAST(image(area)(cv::Rect(x0, y0, x1 - x0, y1 - y0)), weak, options_.min_fast_threshold, true);
      for (auto k : weak) {
        k.pt.x += x0;
        k.pt.y += y0;
        if (inside(k.pt) && cell_of(k.pt) == cell) kept.push_back(k);
      }
    }
  }
  for (auto& k : kept) {
    k.pt.x += area.x;
    k.pt.y += area.y;
  }
  const cv::Rect inner(kEdgeThreshold, kEdgeThreshold, image.cols - 2 * kEdgeThreshold,
                       image.rows - 2 * kEdgeThreshold);
  return Distribute(std::move(kept), inner, features_per_level_[level]);
}

std::vector<cv::KeyPoint> OrbExtractor::Distribute(std::vector<cv::KeyPoint> candidates, const cv::Rect& area,
                                                   int wanted) const {
  if (wanted <= 0 || candidates.empty()) return {};
  if (static_cast<int>(candidates.size()) <= wanted) return candidates;
  // Root nodes: squares of about the area's height across its width.
  const int roots = std::max(1, static_cast<int>(std::lround(static_cast<double>(area.width) / area.height)));
  const float root_w = static_cast<float>(area.width) / roots;
  std::list<QuadNode> nodes;
  std::vector<QuadNode*> root_nodes;
  for (int i = 0; i < roots; ++i) {
    QuadNode node;
    node.top_left = {area.x + i * root_w, static_cast<float>(area.y)};
    node.bottom_right = {area.x + (i + 1) * root_w, static_cast<float>(area.y + area.height)};
    nodes.push_back(node);
    root_nodes.push_back(&nodes.back());
  }
  for (const auto& k : candidates) {
    const int i = std::clamp(static_cast<int>((k.pt.x - area.x) / root_w), 0, roots - 1);
    root_nodes[i]->points.push_back(k);
  }
  nodes.remove_if([](const QuadNode& n) { return n.points.empty(); });
  // Split nodes holding several points until there are enough nodes; near the end, split the
  // most crowded first so the last split does not overshoot much.
  std::array<QuadNode, 4> children;
  while (static_cast<int>(nodes.size()) < wanted) {
    const size_t before = nodes.size();
    std::vector<std::list<QuadNode>::iterator> splittable;
    for (auto it = nodes.begin(); it != nodes.end(); ++it) {
      if (it->Splittable()) splittable.push_back(it);
    }
    if (splittable.empty()) break;
    const int growth_if_all = static_cast<int>(splittable.size()) * 3;
    if (static_cast<int>(nodes.size()) + growth_if_all > wanted) {
      std::sort(splittable.begin(), splittable.end(),
                [](const auto& a, const auto& b) { return a->points.size() > b->points.size(); });
    }
    for (auto it : splittable) {
      it->Split(&children);
      for (auto& child : children) {
        if (!child.points.empty()) nodes.push_back(std::move(child));
      }
      nodes.erase(it);
      if (static_cast<int>(nodes.size()) >= wanted) break;
    }
    if (nodes.size() == before) break;
  }
  std::vector<cv::KeyPoint> result;
  result.reserve(nodes.size());
  for (const auto& node : nodes) {
    result.push_back(
        *std::max_element(node.points.begin(), node.points.end(),
                          [](const cv::KeyPoint& a, const cv::KeyPoint& b) { return a.response < b.response; }));
  }
  return result;
}

float OrbExtractor::Orientation(const cv::Mat& image, const cv::Point2f& point) const {
  const int cx = cvRound(point.x), cy = cvRound(point.y);
  const int step = static_cast<int>(image.step1());
  const uint8_t* center = image.ptr<uint8_t>(cy) + cx;
  int m01 = 0, m10 = 0;
  for (int u = -kHalfPatchSize; u <= kHalfPatchSize; ++u) m10 += u * center[u];
  for (int v = 1; v <= kHalfPatchSize; ++v) {
    int v_sum = 0;
    const int d = circle_extent_[v];
    for (int u = -d; u <= d; ++u) {
      const int below = center[u + v * step], above = center[u - v * step];
      v_sum += below - above;
      m10 += u * (below + above);
    }
    m01 += v * v_sum;
  }
  float angle = static_cast<float>(cv::fastAtan2(static_cast<float>(m01), static_cast<float>(m10)));
  return angle;
}

void OrbExtractor::Extract(const cv::Mat& image, std::vector<cv::KeyPoint>* keypoints, cv::Mat* descriptors) {
  if (image.empty() || image.type() != CV_8UC1) throw Error("OrbExtractor: expected a non-empty 8-bit gray image");
  if (options_.detector == "opencv") {
    describer_->detectAndCompute(image, cv::noArray(), *keypoints, *descriptors);
    return;
  }
  BuildPyramid(image);
  // Levels are independent once the pyramid stands: with helper threads, each takes the next.
  std::vector<std::vector<cv::KeyPoint>> per_level(options_.num_levels);
  runner_->Run(options_.num_levels, [&](int level) {
    std::vector<cv::KeyPoint>& points = per_level[level];
    points = DetectLevel(level);
    const float scale = scale_factors_[level];
    for (auto& k : points) {
      k.angle = Orientation(pyramid_[level], k.pt);
      k.octave = level;
      k.size = kPatchSize * scale;
      k.pt *= scale;
    }
  });
  std::vector<cv::KeyPoint> all;
  all.reserve(options_.num_features);
  for (auto& points : per_level) {
    for (auto& k : points) {
      k.class_id = static_cast<int>(all.size());
      all.push_back(k);
    }
  }
  // OpenCV's ORB describes provided keypoints (grouped by level, possibly dropping some at the
  // border); class_id carries each keypoint's place back.
  std::vector<cv::KeyPoint> described = all;
  cv::Mat raw;
  describer_->compute(image, described, raw);
  keypoints->clear();
  keypoints->reserve(described.size());
  descriptors->create(static_cast<int>(described.size()), 32, CV_8U);
  std::vector<int> order(described.size());
  for (size_t i = 0; i < described.size(); ++i) order[i] = static_cast<int>(i);
  std::sort(order.begin(), order.end(), [&](int a, int b) { return described[a].class_id < described[b].class_id; });
  for (size_t row = 0; row < order.size(); ++row) {
    cv::KeyPoint k = all[described[order[row]].class_id];
    k.class_id = -1;
    keypoints->push_back(k);
    raw.row(order[row]).copyTo(descriptors->row(static_cast<int>(row)));
  }
}

}  // namespace stitch
