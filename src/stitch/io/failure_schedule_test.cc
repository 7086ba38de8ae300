#include "stitch/io/failure_schedule.h"

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "stitch/util/error.h"

namespace stitch {
namespace {

TEST(FailureSchedule, ParsesWindows) {
  const FailureSchedule s = FailureSchedule::Parse("400:10,120:8");
  ASSERT_EQ(s.windows().size(), 2u);
  EXPECT_EQ(s.windows()[0].start, 120);
  EXPECT_TRUE(s.Contains(120));
  EXPECT_TRUE(s.Contains(127));
  EXPECT_FALSE(s.Contains(128));
  EXPECT_TRUE(s.Contains(409));
  EXPECT_EQ(s.CountWithin(405), 8 + 5);
  EXPECT_EQ(s.ToString(), "120:8,400:10");
  EXPECT_TRUE(FailureSchedule::Parse("none").empty());
}

TEST(FailureSchedule, RejectsMalformedText) {
  for (const char* bad : {"12", "a:3", "3:", "5:0", "-1:3", "10:5,12:3", "1:2,", "1:2x"}) {
    EXPECT_THROW(FailureSchedule::Parse(bad), Error) << bad;
  }
}

TEST(FailureSchedule, DefaultHasThreeGusts) {
  const FailureSchedule s = FailureSchedule::DefaultGusts(1000);
  ASSERT_EQ(s.windows().size(), 3u);
  EXPECT_EQ(s.windows()[0].start, 200);
  EXPECT_EQ(s.CountWithin(1000), 36);
}

TEST(SpoilImage, MakesFramesUnusableReproducibly) {
  cv::Mat image(120, 160, CV_8U);
  cv::randu(image, 0, 255);
  cv::Mat black = image.clone(), blur_a = image.clone(), blur_b = image.clone();
  SpoilImage(&black, FailureStyle::kBlack, 3, 1);
  EXPECT_EQ(cv::countNonZero(black), 0);
  SpoilImage(&blur_a, FailureStyle::kBlurJump, 3, 1);
  SpoilImage(&blur_b, FailureStyle::kBlurJump, 3, 1);
  EXPECT_EQ(cv::norm(blur_a, blur_b, cv::NORM_INF), 0);
  // Heavy blur removes most of the high-frequency content of random texture.
  cv::Mat dx_before, dx_after;
  cv::Sobel(image, dx_before, CV_32F, 1, 0);
  cv::Sobel(blur_a, dx_after, CV_32F, 1, 0);
  EXPECT_LT(cv::norm(dx_after), 0.5 * cv::norm(dx_before));
}

}  // namespace
}  // namespace stitch
