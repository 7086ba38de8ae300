#include "stitch/synthetic/camera_imperfections.h"

#include <cmath>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "stitch/util/rng.h"

namespace stitch {

bool CameraImperfectionOptions::Check(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = "synthetic.camera." + m;
    return false;
  };
  if (!(rolling_shutter_line_us >= 0 && rolling_shutter_line_us <= 1000))
    return fail("rolling_shutter_line_us must be in [0, 1000]");
  if (rolling_shutter_bands < 1 || rolling_shutter_bands > 64) return fail("rolling_shutter_bands must be in [1, 64]");
  if (!(std::abs(lens_k1) <= 1 && std::abs(lens_k2) <= 1)) return fail("lens_k1 and lens_k2 must be in [-1, 1]");
  if (!(vignetting >= 0 && vignetting < 1)) return fail("vignetting must be in [0, 1)");
  if (!(exposure_step >= 0 && exposure_step < 1)) return fail("exposure_step must be in [0, 1)");
  if (!(exposure_step_interval_s > 0 && exposure_step_interval_s <= 3600))
    return fail("exposure_step_interval_s must be in (0, 3600]");
  if (!(exposure_settle_s > 0 && exposure_settle_s <= 60)) return fail("exposure_settle_s must be in (0, 60]");
  if (!(exposure_time_ms >= 0 && exposure_time_ms <= 1000)) return fail("exposure_time_ms must be in [0, 1000]");
  if (!(dirty_patch >= 0 && dirty_patch <= 0.5)) return fail("dirty_patch must be in [0, 0.5]");
  if (jpeg_quality < 0 || jpeg_quality > 100) return fail("jpeg_quality must be in [0, 100]");
  return true;
}

ImageImperfections::ImageImperfections(const CameraImperfectionOptions& options, int width, int height, int num_frames,
                                       double fps, uint64_t seed)
    : options_(options) {
  const double cx = (width - 1) / 2.0, cy = (height - 1) / 2.0;
  if (options_.vignetting > 0) {
    // A natural fall-off, 1 - v (r / r_corner)^2, so the corners keep 1 - v of their light.
    vignette_.create(height, width, CV_32F);
    const double corner2 = cx * cx + cy * cy;
    for (int y = 0; y < height; ++y) {
      auto* row = vignette_.ptr<float>(y);
      for (int x = 0; x < width; ++x) {
        const double r2 = ((x - cx) * (x - cx) + (y - cy) * (y - cy)) / corner2;
        row[x] = static_cast<float>(1.0 - options_.vignetting * r2);
      }
    }
  }
  if (options_.dirty_patch > 0) {
    // An ellipse in the lower left quarter covering the stated fraction, its edge soft.
    patch_ = cv::Mat::zeros(height, width, CV_32F);
    const double area = options_.dirty_patch * width * height;
    const double a = std::sqrt(area / M_PI * 1.5), b = area / (M_PI * a);
    cv::ellipse(patch_, cv::Point(static_cast<int>(0.3 * width), static_cast<int>(0.68 * height)),
                cv::Size(static_cast<int>(a), static_cast<int>(b)), 20, 0, 360, cv::Scalar(1.0), cv::FILLED);
    const int soft = 2 * static_cast<int>(0.1 * std::min(a, b)) + 1;
    cv::GaussianBlur(patch_, patch_, cv::Size(soft, soft), 0);
  }
  if (options_.exposure_step > 0 && num_frames > 0) {
    // Steps at random times (exponential gaps), each up or down, each decaying as the control
    // brings the exposure back.
    Rng rng(HashU64(seed, 0x65787073));
    std::vector<std::pair<double, double>> steps;  // time, signed size
    for (double t = -std::log(1.0 - rng.Uniform()) * options_.exposure_step_interval_s; t < num_frames / fps;
         t += -std::log(1.0 - rng.Uniform()) * options_.exposure_step_interval_s) {
      steps.emplace_back(t, (rng.Uniform() < 0.5 ? -1.0 : 1.0) * options_.exposure_step);
    }
    gain_.assign(static_cast<size_t>(num_frames), 1.0);
    for (int i = 0; i < num_frames; ++i) {
      const double t = i / fps;
      for (const auto& [at, size] : steps) {
        if (at <= t) gain_[static_cast<size_t>(i)] += size * std::exp(-(t - at) / options_.exposure_settle_s * 3.0);
      }
      gain_[static_cast<size_t>(i)] = std::max(0.2, gain_[static_cast<size_t>(i)]);
    }
  }
}

void ImageImperfections::ApplyOptics(int frame, cv::Mat* image) const {
  const double gain = ExposureGain(frame);
  if (vignette_.empty() && patch_.empty() && gain == 1.0) return;
  cv::Mat light;
  image->convertTo(light, CV_32F, gain);
  if (!vignette_.empty()) light = light.mul(vignette_);
  if (!patch_.empty()) {
    // Under the smudge: the scene blurred and washed out towards a bright haze.
    cv::Mat smudged;
    cv::GaussianBlur(light, smudged, cv::Size(0, 0), 6.0);
    smudged = 0.45 * smudged + 0.55 * 200.0;
    light = light.mul(1.0 - patch_) + smudged.mul(patch_);
  }
  light.convertTo(*image, CV_8U);
}

void ImageImperfections::ApplyCompression(cv::Mat* image) const {
  if (options_.jpeg_quality <= 0) return;
  std::vector<uint8_t> bytes;
  cv::imencode(".jpg", *image, bytes, {cv::IMWRITE_JPEG_QUALITY, options_.jpeg_quality});
  *image = cv::imdecode(bytes, cv::IMREAD_GRAYSCALE);
}

}  // namespace stitch
