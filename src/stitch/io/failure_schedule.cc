#include "stitch/io/failure_schedule.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include "stitch/util/error.h"
#include "stitch/util/rng.h"

namespace stitch {

FailureSchedule::FailureSchedule(std::vector<FailureWindow> windows) : windows_(std::move(windows)) {
  std::sort(windows_.begin(), windows_.end(),
            [](const FailureWindow& a, const FailureWindow& b) { return a.start < b.start; });
  for (size_t i = 0; i < windows_.size(); ++i) {
    if (windows_[i].start < 0 || windows_[i].length <= 0) {
      throw Error(Str() << "failure window " << windows_[i].start << ":" << windows_[i].length
                        << ": start must be >= 0 and length > 0");
    }
    if (i > 0 && windows_[i].start < windows_[i - 1].end()) {
      throw Error(Str() << "failure windows " << windows_[i - 1].start << ":" << windows_[i - 1].length << " and "
                        << windows_[i].start << ":" << windows_[i].length << " overlap");
    }
  }
}

FailureSchedule FailureSchedule::Parse(const std::string& text) {
  if (text.empty() || text == "none") return FailureSchedule();
  if (text.front() == ',' || text.back() == ',' || text.find(",,") != std::string::npos) {
    throw Error("--failures: '" + text + "' has an empty entry (use FRAME:LENGTH,FRAME:LENGTH)");
  }
  std::vector<FailureWindow> windows;
  std::stringstream pieces(text);
  std::string piece;
  while (std::getline(pieces, piece, ',')) {
    const auto colon = piece.find(':');
    size_t used_start = 0, used_length = 0;
    FailureWindow window;
    try {
      if (colon == std::string::npos) throw std::invalid_argument("no colon");
      window.start = std::stoi(piece.substr(0, colon), &used_start);
      window.length = std::stoi(piece.substr(colon + 1), &used_length);
    } catch (const std::exception&) {
      throw Error("--failures: '" + piece + "' is not FRAME:LENGTH (e.g. 120:8,400:10, or none)");
    }
    if (used_start != colon || used_length != piece.size() - colon - 1) {
      throw Error("--failures: '" + piece + "' is not FRAME:LENGTH (e.g. 120:8,400:10, or none)");
    }
    windows.push_back(window);
  }
  try {
    return FailureSchedule(std::move(windows));
  } catch (const Error& e) {
    throw Error(std::string("--failures: ") + e.what());
  }
}

FailureSchedule FailureSchedule::DefaultGusts(int num_frames) {
  const int length = std::max(1, std::min(12, num_frames / 20));
  std::vector<FailureWindow> windows;
  for (double at : {0.20, 0.45, 0.70}) {
    windows.push_back({static_cast<int>(at * num_frames), length});
  }
  return FailureSchedule(std::move(windows));
}

bool FailureSchedule::Contains(int frame) const {
  for (const auto& w : windows_) {
    if (frame >= w.start && frame < w.end()) return true;
  }
  return false;
}

int FailureSchedule::CountWithin(int num_frames) const {
  int count = 0;
  for (const auto& w : windows_) {
    count += std::max(0, std::min(w.end(), num_frames) - std::max(w.start, 0));
  }
  return count;
}

std::string FailureSchedule::ToString() const {
  if (windows_.empty()) return "none";
  std::string text;
  for (const auto& w : windows_) {
    text += (text.empty() ? "" : ",") + std::to_string(w.start) + ":" + std::to_string(w.length);
  }
  return text;
}

FailureStyle ParseFailureStyle(const std::string& name) {
  if (name == "black") return FailureStyle::kBlack;
  if (name == "blur") return FailureStyle::kBlurJump;
  throw Error("--failure-style: '" + name + "' is not one of black, blur");
}

void ApplyMotionBlur(cv::Mat* image, double length_px, double angle_rad) {
  const int size = std::max(3, static_cast<int>(std::ceil(length_px)) | 1);
  cv::Mat kernel = cv::Mat::zeros(size, size, CV_32F);
  const cv::Point2d centre(size / 2.0, size / 2.0);
  const cv::Point2d half(0.5 * length_px * std::cos(angle_rad), 0.5 * length_px * std::sin(angle_rad));
  cv::line(kernel, centre - half, centre + half, cv::Scalar(1.0), 1, cv::LINE_AA);
  kernel /= cv::sum(kernel)[0];
  cv::filter2D(*image, *image, -1, kernel, cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
}

void SpoilImage(cv::Mat* image, FailureStyle style, int frame_index, uint64_t seed) {
  if (style == FailureStyle::kBlack) {
    image->setTo(cv::Scalar(0));
    return;
  }
  Rng rng(HashU64(seed, static_cast<uint64_t>(frame_index), 0x5b0));
  // The jump: a large shift and rotation, as if the camera was knocked away...
  const cv::Point2f centre(image->cols / 2.0f, image->rows / 2.0f);
  cv::Mat warp = cv::getRotationMatrix2D(centre, rng.Uniform(-40, 40), rng.Uniform(0.8, 1.25));
  warp.at<double>(0, 2) += rng.Uniform(-0.3, 0.3) * image->cols;
  warp.at<double>(1, 2) += rng.Uniform(-0.3, 0.3) * image->rows;
  cv::warpAffine(*image, *image, warp, image->size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
  // ...and heavy motion blur while it moved.
  ApplyMotionBlur(image, rng.Uniform(0.06, 0.1) * image->cols, rng.Uniform(0, M_PI));
}

}  // namespace stitch
