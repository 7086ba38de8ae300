#include "stitch/features/orb_extractor.h"

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "stitch/features/descriptor.h"
#include "stitch/synthetic/synthetic_sequence.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

cv::Mat SyntheticImage(int frame = 30) {
  SyntheticOptions options;
  options.flight.num_frames = 100;
  options.flight.num_strips = 1;
  options.flight.strip_length_m = 100;
  static SyntheticSequence* sequence = new SyntheticSequence(options, FailureSchedule());
  return sequence->RenderFrame(frame);
}

TEST(OrbExtractor, FindsTheRequestedNumberSpreadOverImageAndScales) {
  OrbExtractor extractor{OrbOptions{}};
  const cv::Mat image = SyntheticImage();
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;
  extractor.Extract(image, &keypoints, &descriptors);
  EXPECT_GE(keypoints.size(), 900u);
  EXPECT_LE(keypoints.size(), 1100u);
  EXPECT_EQ(descriptors.rows, static_cast<int>(keypoints.size()));
  EXPECT_EQ(descriptors.cols, 32);
  // Every cell of a 4x4 grid holds features, and every level contributes.
  std::vector<int> cells(16, 0), levels(8, 0);
  for (const auto& k : keypoints) {
    ASSERT_GE(k.pt.x, 15.0f);
    ASSERT_GE(k.pt.y, 15.0f);
    ASSERT_LT(k.pt.x, image.cols - 15.0f);
    ASSERT_LT(k.pt.y, image.rows - 15.0f);
    ++cells[std::min(3, static_cast<int>(4 * k.pt.y / image.rows)) * 4 +
            std::min(3, static_cast<int>(4 * k.pt.x / image.cols))];
    ASSERT_GE(k.octave, 0);
    ASSERT_LT(k.octave, 8);
    ++levels[k.octave];
  }
  for (int c = 0; c < 16; ++c) EXPECT_GT(cells[c], 20) << "cell " << c;
  for (int l = 0; l < 8; ++l) EXPECT_GT(levels[l], 10) << "level " << l;
}

TEST(OrbExtractor, DescriptorsAreRotationInvariant) {
  OrbExtractor extractor{OrbOptions{}};
  const cv::Mat image = SyntheticImage();
  cv::Mat rotated;
  cv::rotate(image, rotated, cv::ROTATE_90_CLOCKWISE);
  std::vector<cv::KeyPoint> a, b;
  cv::Mat da, db;
  extractor.Extract(image, &a, &da);
  extractor.Extract(rotated, &b, &db);
  // (x, y) -> (rows - 1 - y, x) under a clockwise quarter turn.
  std::vector<int> distances;
  std::vector<double> angle_errors;
  for (size_t i = 0; i < a.size(); ++i) {
    if (a[i].octave > 1) continue;
    const cv::Point2f expected(image.rows - 1 - a[i].pt.y, a[i].pt.x);
    for (size_t j = 0; j < b.size(); ++j) {
      if (b[j].octave != a[i].octave || cv::norm(b[j].pt - expected) > 0.5) continue;
      distances.push_back(HammingDistance(da.ptr<uint8_t>(static_cast<int>(i)), db.ptr<uint8_t>(static_cast<int>(j))));
      angle_errors.push_back(std::abs(std::remainder(b[j].angle - a[i].angle - 90.0, 360.0)));
    }
  }
  ASSERT_GT(distances.size(), 100u);
  std::nth_element(distances.begin(), distances.begin() + distances.size() / 2, distances.end());
  std::nth_element(angle_errors.begin(), angle_errors.begin() + angle_errors.size() / 2, angle_errors.end());
  EXPECT_LT(distances[distances.size() / 2], 25) << "median Hamming distance of the same corner, rotated";
  EXPECT_LT(angle_errors[angle_errors.size() / 2], 3.0) << "median orientation error, degrees";
}

TEST(OrbExtractor, IsRepeatableAndDeterministic) {
  OrbExtractor extractor{OrbOptions{}};
  const cv::Mat image = SyntheticImage();
  std::vector<cv::KeyPoint> a, b, shifted;
  cv::Mat da, db, ds;
  extractor.Extract(image, &a, &da);
  extractor.Extract(image, &b, &db);
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(cv::norm(da, db, cv::NORM_HAMMING), 0);
  // The next frame of the flight: most corners of the previous frame are found again.
  const cv::Mat next = SyntheticImage(31);
  extractor.Extract(next, &shifted, &ds);
  int matched = 0;
  for (int i = 0; i < da.rows; ++i) {
    int best = 257;
    for (int j = 0; j < ds.rows; ++j) best = std::min(best, HammingDistance(da.ptr<uint8_t>(i), ds.ptr<uint8_t>(j)));
    matched += best < kDescriptorDistanceLow;
  }
  EXPECT_GT(matched, da.rows / 2);
}

TEST(OrbExtractor, HelperThreadsGiveTheSameFeatures) {
  OrbOptions two_threads;
  two_threads.threads = 2;
  OrbExtractor one{OrbOptions{}}, two{two_threads};
  for (int frame : {10, 30, 31}) {
    const cv::Mat image = SyntheticImage(frame);
    std::vector<cv::KeyPoint> a, b;
    cv::Mat da, db;
    one.Extract(image, &a, &da);
    two.Extract(image, &b, &db);
    ASSERT_EQ(a.size(), b.size());
    for (size_t i = 0; i < a.size(); ++i) {
      EXPECT_EQ(a[i].pt, b[i].pt);
      EXPECT_EQ(a[i].octave, b[i].octave);
      EXPECT_EQ(a[i].angle, b[i].angle);
    }
    EXPECT_EQ(cv::norm(da, db, cv::NORM_HAMMING), 0);
  }
}

TEST(OrbExtractor, WeakCornersOnlyWhereNoStrongOnes) {
  // Squares on a plain ground, their corners of high contrast on the left half, faint (below
  // the preferred threshold) on the right. Both halves get features, the right ones all weak.
  cv::Mat image(480, 640, CV_8U, cv::Scalar(100));
  for (int y = 8; y + 10 < 480; y += 24) {
    for (int x = 8; x + 10 < 640; x += 24) {
      const int value = x < 320 ? 200 : 112;
      image(cv::Rect(x, y, 10, 10)).setTo(value);
    }
  }
  cv::GaussianBlur(image, image, cv::Size(3, 3), 0.8);  // a lens: one strongest pixel per corner
  OrbExtractor extractor{OrbOptions{}};
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;
  extractor.Extract(image, &keypoints, &descriptors);
  int left = 0, right = 0;
  for (const auto& k : keypoints) {
    if (k.octave != 0) continue;
    if (k.pt.x < 300) {
      ++left;
      EXPECT_GE(k.response, 20.0f);
    } else if (k.pt.x > 340) {
      ++right;
      EXPECT_LT(k.response, 20.0f);
      EXPECT_GE(k.response, 7.0f);
    }
  }
  EXPECT_GT(left, 20);
  EXPECT_GT(right, 20);
}

TEST(OrbExtractor, RejectsBadInput) {
  OrbExtractor extractor{OrbOptions{}};
  std::vector<cv::KeyPoint> k;
  cv::Mat d;
  EXPECT_THROW(extractor.Extract(cv::Mat(), &k, &d), Error);
  EXPECT_THROW(extractor.Extract(cv::Mat(100, 100, CV_8UC3), &k, &d), Error);
  OrbOptions bad;
  bad.scale_factor = 0.9;
  EXPECT_THROW(OrbExtractor{bad}, Error);
  // A blank image has no features, and that is not an error.
  extractor.Extract(cv::Mat(480, 640, CV_8U, cv::Scalar(128)), &k, &d);
  EXPECT_TRUE(k.empty());
}

}  // namespace
}  // namespace stitch
