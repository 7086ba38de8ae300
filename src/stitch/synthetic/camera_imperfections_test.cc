#include "stitch/synthetic/camera_imperfections.h"

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "stitch/synthetic/synthetic_sequence.h"

namespace stitch {
namespace {

SyntheticOptions ShortStrip() {
  SyntheticOptions options;
  options.flight.num_frames = 40;
  options.flight.num_strips = 1;
  options.flight.strip_length_m = 80;
  options.world.num_buildings = 6;
  options.noise_sigma = 0;
  return options;
}

double GradientEnergy(const cv::Mat& image) {
  cv::Mat dx, dy;
  cv::Sobel(image, dx, CV_32F, 1, 0);
  cv::Sobel(image, dy, CV_32F, 0, 1);
  return cv::mean(dx.mul(dx) + dy.mul(dy))[0];
}

double MeanAbsoluteDifference(const cv::Mat& a, const cv::Mat& b) {
  cv::Mat difference;
  cv::absdiff(a, b, difference);
  return cv::mean(difference)[0];
}

// Off by default: the photometric flaws leave a frame as it is, and the camera has no distortion.
TEST(CameraImperfections, NoneByDefault) {
  const ImageImperfections flaws(CameraImperfectionOptions(), 640, 480, 40, 20, 1);
  const cv::Mat frame = SyntheticSequence(ShortStrip(), FailureSchedule()).RenderFrame(7);
  cv::Mat image = frame.clone();
  flaws.ApplyOptics(7, &image);
  flaws.ApplyCompression(&image);
  EXPECT_EQ(MeanAbsoluteDifference(frame, image), 0.0);
  EXPECT_EQ(flaws.ExposureGain(7), 1.0);
  EXPECT_FALSE(ShortStrip().MakeCamera().HasDistortion());
  EXPECT_EQ(CameraImperfectionOptions().rolling_shutter_line_us, 0);
  EXPECT_EQ(CameraImperfectionOptions().exposure_time_ms, 0);
}

TEST(CameraImperfections, VignettingDarkensTheCornersByItsFraction) {
  CameraImperfectionOptions options;
  options.vignetting = 0.4;
  const ImageImperfections flaws(options, 640, 480, 10, 20, 1);
  cv::Mat image(480, 640, CV_8UC1, cv::Scalar(200));
  flaws.ApplyOptics(0, &image);
  EXPECT_NEAR(image.at<uint8_t>(240, 320), 200, 1);
  EXPECT_NEAR(image.at<uint8_t>(0, 0), 120, 1);
  EXPECT_NEAR(image.at<uint8_t>(479, 639), 120, 1);
  EXPECT_NEAR(image.at<uint8_t>(240, 0), 200 * (1 - 0.4 * 319.5 * 319.5 / (319.5 * 319.5 + 239.5 * 239.5)), 1);
}

TEST(CameraImperfections, AutoExposureStepsAndSettlesBack) {
  CameraImperfectionOptions options;
  options.exposure_step = 0.3;
  options.exposure_step_interval_s = 3;
  options.exposure_settle_s = 1;
  const ImageImperfections flaws(options, 64, 48, 1200, 20, 5), again(options, 64, 48, 1200, 20, 5);
  double low = 1, high = 1;
  int settled = 0;
  for (int i = 0; i < 1200; ++i) {
    EXPECT_EQ(flaws.ExposureGain(i), again.ExposureGain(i)) << "deterministic from the seed";
    low = std::min(low, flaws.ExposureGain(i));
    high = std::max(high, flaws.ExposureGain(i));
    settled += std::abs(flaws.ExposureGain(i) - 1) < 0.03;
  }
  EXPECT_GT(high, 1.25);  // steps both ways, of about their size...
  EXPECT_LT(low, 0.75);
  EXPECT_GT(settled, 200);  // ...and the control brings the exposure back between them
  cv::Mat image(48, 64, CV_8UC1, cv::Scalar(100));
  int brightest = 0;
  for (int i = 0; i < 1200; ++i) brightest = flaws.ExposureGain(i) > flaws.ExposureGain(brightest) ? i : brightest;
  flaws.ApplyOptics(brightest, &image);
  EXPECT_NEAR(image.at<uint8_t>(10, 10), 100 * high, 1);
}

TEST(CameraImperfections, ADirtyPatchWashesOutItsShareOfTheImage) {
  SyntheticOptions options = ShortStrip();
  const cv::Mat clean = SyntheticSequence(options, FailureSchedule()).RenderFrame(5);
  options.camera.dirty_patch = 0.1;
  const cv::Mat dirty = SyntheticSequence(options, FailureSchedule()).RenderFrame(5);
  cv::Mat changed;
  cv::absdiff(clean, dirty, changed);
  const double share = cv::countNonZero(changed > 8) / static_cast<double>(changed.total());
  EXPECT_GT(share, 0.05);
  EXPECT_LT(share, 0.15);
  // Where it lies, little texture is left.
  const cv::Rect centre_of_patch(static_cast<int>(0.3 * 640) - 30, static_cast<int>(0.68 * 480) - 20, 60, 40);
  EXPECT_LT(GradientEnergy(dirty(centre_of_patch)), 0.2 * GradientEnergy(clean(centre_of_patch)));
}

TEST(CameraImperfections, JpegCompressionLosesMoreAtLowerQuality) {
  SyntheticOptions options = ShortStrip();
  const cv::Mat clean = SyntheticSequence(options, FailureSchedule()).RenderFrame(5);
  options.camera.jpeg_quality = 95;
  const cv::Mat fine = SyntheticSequence(options, FailureSchedule()).RenderFrame(5);
  options.camera.jpeg_quality = 20;
  const cv::Mat coarse = SyntheticSequence(options, FailureSchedule()).RenderFrame(5);
  EXPECT_GT(MeanAbsoluteDifference(clean, fine), 0.0);
  EXPECT_GT(MeanAbsoluteDifference(clean, coarse), 2 * MeanAbsoluteDifference(clean, fine));
}

TEST(CameraImperfections, TheLensDistortionIsRenderedAndInTheCalibration) {
  SyntheticOptions options = ShortStrip();
  options.camera.lens_k1 = -0.15;
  options.camera.lens_k2 = 0.03;
  const SyntheticSequence sequence(options, FailureSchedule());
  ASSERT_TRUE(sequence.camera().HasDistortion());
  EXPECT_DOUBLE_EQ(sequence.camera().params()[4], -0.15);
  EXPECT_DOUBLE_EQ(sequence.camera().params()[5], 0.03);
  const cv::Mat plain = SyntheticSequence(ShortStrip(), FailureSchedule()).RenderFrame(5);
  EXPECT_GT(MeanAbsoluteDifference(plain, sequence.RenderFrame(5)), 5.0);
}

// The camera's own motion over a long exposure blurs the frame, outside gusts too.
TEST(CameraImperfections, ALongExposureBlursByTheCamerasMotion) {
  SyntheticOptions options = ShortStrip();
  const cv::Mat sharp = SyntheticSequence(options, FailureSchedule()).RenderFrame(5);
  options.camera.exposure_time_ms = 40;  // most of a 50 ms frame: about 5 pixels at 1 m a frame, 70 m up
  const cv::Mat blurred = SyntheticSequence(options, FailureSchedule()).RenderFrame(5);
  EXPECT_LT(GradientEnergy(blurred), 0.7 * GradientEnergy(sharp));
  options.camera.exposure_time_ms = 2;  // a bright day's shutter: under a pixel, left sharp
  EXPECT_EQ(MeanAbsoluteDifference(sharp, SyntheticSequence(options, FailureSchedule()).RenderFrame(5)), 0.0);
}

// Read out over a whole frame period, the last rows see the scene as the next frame does, the
// first rows as this one does.
TEST(CameraImperfections, ARollingShuttersRowsAreSeenAtTheirReadoutTimes) {
  SyntheticOptions options = ShortStrip();
  const SyntheticSequence global(options, FailureSchedule());
  options.camera.rolling_shutter_line_us = 1e6 / (options.flight.fps * options.height);
  options.camera.rolling_shutter_bands = 12;
  const SyntheticSequence rolling(options, FailureSchedule());
  const cv::Mat frame = rolling.RenderFrame(5), now = global.RenderFrame(5), next = global.RenderFrame(6);
  const cv::Range top(0, 40), bottom(440, 480);
  EXPECT_LT(MeanAbsoluteDifference(frame.rowRange(top), now.rowRange(top)),
            0.5 * MeanAbsoluteDifference(frame.rowRange(top), next.rowRange(top)));
  EXPECT_LT(MeanAbsoluteDifference(frame.rowRange(bottom), next.rowRange(bottom)),
            0.5 * MeanAbsoluteDifference(frame.rowRange(bottom), now.rowRange(bottom)));
}

TEST(CameraImperfections, SettingsOutOfRangeAreRefused) {
  CameraImperfectionOptions options;
  std::string why;
  EXPECT_TRUE(options.Check(&why)) << why;
  options.jpeg_quality = 101;
  EXPECT_FALSE(options.Check(&why));
  EXPECT_NE(why.find("synthetic.camera.jpeg_quality"), std::string::npos) << why;
  options = CameraImperfectionOptions();
  options.vignetting = 1;
  EXPECT_FALSE(options.Check(&why));
  options = CameraImperfectionOptions();
  options.rolling_shutter_bands = 0;
  EXPECT_FALSE(options.Check(&why));
}

}  // namespace
}  // namespace stitch
