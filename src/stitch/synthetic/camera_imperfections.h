#pragma once
// What a real camera does to the synthetic flight's frames, each on its own setting and off by
// default (the default flight stays as it is), so the gate can predict real footage: a rolling
// shutter, lens distortion (rendered, and in the calibration the run reads), vignetting,
// auto-exposure steps, motion blur from the camera's motion over the exposure (outside gusts
// too), a dirty patch of the lens, and JPEG compression. The renderer does the geometry (the
// rolling shutter's bands, the distortion); ImageImperfections does the photometry, per frame,
// deterministically from the seed.

#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace stitch {

struct CameraImperfectionOptions {
  double rolling_shutter_line_us = 0;   // readout delay from one image row to the next (0: global shutter)
  int rolling_shutter_bands = 6;        // rendered bands, each at its rows' mid readout time
  double lens_k1 = 0, lens_k2 = 0;      // radial distortion (OpenCV's k1, k2), rendered and in the calibration
  double vignetting = 0;                // brightness lost in the image's corners, fraction
  double exposure_step = 0;             // auto-exposure: a brightness step of this fraction...
  double exposure_step_interval_s = 5;  // ...on average this often (random times and signs)...
  double exposure_settle_s = 1.5;       // ...that the exposure control takes this long to undo
  double exposure_time_ms = 0;          // motion blur: the camera's motion over this exposure (0: none)
  double dirty_patch = 0;               // fraction of the image under a smudge on the lens (blurred, washed out)
  int jpeg_quality = 0;                 // each frame compressed at this JPEG quality, 1-100 (0: not)

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("rolling_shutter_line_us", rolling_shutter_line_us,
      "rolling shutter: readout delay from one image row to the next, microseconds (0: global shutter)");
    v("rolling_shutter_bands", rolling_shutter_bands,
      "rolling shutter: the frame is rendered in this many bands of rows, each at its rows' mid readout time");
    v("lens_k1", lens_k1, "radial lens distortion k1 (OpenCV's), rendered and in the calibration");
    v("lens_k2", lens_k2, "radial lens distortion k2 (OpenCV's)");
    v("vignetting", vignetting, "brightness lost in the image's corners, fraction (0: none)");
    v("exposure_step", exposure_step, "auto-exposure: brightness steps of this fraction at random times (0: none)");
    v("exposure_step_interval_s", exposure_step_interval_s, "auto-exposure: mean time between steps, seconds");
    v("exposure_settle_s", exposure_settle_s, "auto-exposure: time the control takes to undo a step, seconds");
    v("exposure_time_ms", exposure_time_ms,
      "motion blur from the camera's own motion over this exposure time, milliseconds (0: none; gusts blur anyway)");
    v("dirty_patch", dirty_patch, "fraction of the image under a smudge on the lens, blurred and washed out (0: none)");
    v("jpeg_quality", jpeg_quality, "each frame compressed at this JPEG quality, 1-100 (0: not compressed)");
  }
  bool Check(std::string* why) const;
};

// The photometric imperfections of one flight (everything but the rolling shutter and the lens,
// which the rendering does): made once for the image size, the frame count and rate and the seed.
class ImageImperfections {
 public:
  ImageImperfections(const CameraImperfectionOptions& options, int width, int height, int num_frames, double fps,
                     uint64_t seed);

  // Vignetting, exposure and the dirty patch on a rendered CV_8UC1 frame (before sensor noise).
  void ApplyOptics(int frame, cv::Mat* image) const;
  // JPEG compression (after sensor noise, as a camera's encoder sees it).
  void ApplyCompression(cv::Mat* image) const;
  // The brightness gain of `frame` from auto-exposure (1: none).
  double ExposureGain(int frame) const { return gain_.empty() ? 1.0 : gain_.at(static_cast<size_t>(frame)); }

 private:
  CameraImperfectionOptions options_;
  cv::Mat vignette_;          // CV_32F gain per pixel; empty: none
  cv::Mat patch_;             // CV_32F weight of the smudge per pixel; empty: none
  std::vector<double> gain_;  // per frame; empty: none
};

}  // namespace stitch
