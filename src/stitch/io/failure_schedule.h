#pragma once
// Induced tracking failures, for reproducible evaluation: `--failures FRAME:LENGTH,...` names the
// frames that ingest replaces with unusable ones (on the synthetic flight: gusts).

#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace stitch {

struct FailureWindow {
  int start = 0;   // first affected frame
  int length = 0;  // number of frames
  int end() const { return start + length; }
};

class FailureSchedule {
 public:
  FailureSchedule() = default;
  explicit FailureSchedule(std::vector<FailureWindow> windows);  // sorts; throws on overlap

  // "none" or "" -> empty; "120:8,400:10" -> two windows. Throws stitch::Error with the offending
  // piece for anything else (negative, zero length, overlapping windows).
  static FailureSchedule Parse(const std::string& text);
  // The embedded default: three gusts of 12 frames at 20%, 45% and 70% of the sequence.
  static FailureSchedule DefaultGusts(int num_frames);

  bool Contains(int frame) const;
  // Number of scheduled frames that fall inside [0, num_frames).
  int CountWithin(int num_frames) const;
  const std::vector<FailureWindow>& windows() const { return windows_; }
  bool empty() const { return windows_.empty(); }
  std::string ToString() const;  // the Parse() form, "none" when empty

 private:
  std::vector<FailureWindow> windows_;
};

enum class FailureStyle {
  kBlack,     // an all-black frame
  kBlurJump,  // heavy motion blur of a shifted, rotated copy: looks like a gust hit the camera
};

// Parses "black" or "blur"; throws stitch::Error otherwise.
FailureStyle ParseFailureStyle(const std::string& name);

// Makes a real image unusable in the given style, reproducibly from (seed, frame_index).
void SpoilImage(cv::Mat* image, FailureStyle style, int frame_index, uint64_t seed);

// Heavy linear motion blur of `length_px` at `angle_rad` (used by SpoilImage and the gusts of the
// synthetic flight).
void ApplyMotionBlur(cv::Mat* image, double length_px, double angle_rad);

}  // namespace stitch
