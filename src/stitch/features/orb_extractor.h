#pragma once
// ORB features spread evenly over the image and over scales: FAST corners on an image pyramid,
// kept per cell with an adaptive threshold (strong corners where there are some, weaker ones
// elsewhere), distributed with a quadtree so each region of each level gets its share, oriented
// by the intensity centroid, described with OpenCV's standard ORB descriptor (so vocabularies
// trained for ORB-SLAM apply). Not thread-safe: one extractor per thread (it may run helper
// threads of its own, `threads`).

#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>

namespace stitch {

class ParallelRunner;

struct OrbOptions {
  int num_features = 1000;
  double scale_factor = 1.2;
  int num_levels = 8;
  int fast_threshold = 20;          // preferred FAST threshold
  int min_fast_threshold = 7;       // used in cells where no corner passes the preferred one
  int cell_size = 35;               // pixels; the adaptive threshold works per cell
  std::string detector = "stitch";  // stitch: spread as above; opencv: cv::ORB's own detection (for comparison)
  int threads = 1;                  // threads detecting pyramid levels (the caller's and helpers)

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("num_features", num_features, "ORB features per frame");
    v("scale_factor", scale_factor, "pyramid scale between levels");
    v("num_levels", num_levels, "pyramid levels");
    v("fast_threshold", fast_threshold, "preferred FAST threshold");
    v("min_fast_threshold", min_fast_threshold, "FAST threshold in cells without strong corners");
    v("cell_size", cell_size, "cell size of the adaptive threshold, pixels");
    v("detector", detector, "stitch (features spread over image and scales) or opencv (cv::ORB's strongest corners)");
    v("threads", threads, "threads detecting features on the pyramid's levels (1: the frame loop's own thread only)");
  }
  bool Check(std::string* why) const;
};

class OrbExtractor {
 public:
  explicit OrbExtractor(const OrbOptions& options);
  ~OrbExtractor();
  OrbExtractor(OrbExtractor&&) noexcept;

  // Keypoints in level-0 pixel coordinates of `image` (CV_8UC1), with octave (level), angle
  // (degrees), size and response set; descriptors N x 32 CV_8U in the same order.
  void Extract(const cv::Mat& image, std::vector<cv::KeyPoint>* keypoints, cv::Mat* descriptors);

  const OrbOptions& options() const { return options_; }
  // Per level: scale (>= 1), and the variance factor of a measurement at that level (scale^2).
  const std::vector<float>& scale_factors() const { return scale_factors_; }
  const std::vector<float>& level_sigma2() const { return level_sigma2_; }
  const std::vector<float>& inverse_level_sigma2() const { return inverse_level_sigma2_; }

 private:
  void BuildPyramid(const cv::Mat& image);
  std::vector<cv::KeyPoint> DetectLevel(int level) const;
  std::vector<cv::KeyPoint> Distribute(std::vector<cv::KeyPoint> candidates, const cv::Rect& area, int wanted) const;
  float Orientation(const cv::Mat& level_image, const cv::Point2f& point) const;

  OrbOptions options_;
  std::vector<float> scale_factors_, level_sigma2_, inverse_level_sigma2_;
  std::vector<int> features_per_level_;
  std::vector<int> circle_extent_;  // half-width of the orientation patch per row
  std::vector<cv::Mat> pyramid_;
  std::unique_ptr<ParallelRunner> runner_;
  cv::Ptr<cv::ORB> describer_;
};

}  // namespace stitch
