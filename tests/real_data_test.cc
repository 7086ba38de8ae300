// Readers on the real sequences in ../shared/datasets, when that folder is present (it is not on
// a user's machine: then these tests skip and say so).

#include <filesystem>

#include <gtest/gtest.h>

#include "stitch/io/image_sequence.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

std::string DatasetPath(const std::string& relative) {
  const char* env = std::getenv("STITCH_DATASETS");
  const fs::path root = env ? fs::path(env) : fs::path(STITCH_DATASETS_DIR);
  return (root / relative).string();
}

#define SKIP_UNLESS_PRESENT(path)                                 \
  if (!fs::exists(path))                                          \
  GTEST_SKIP() << path                                            \
               << " is absent: real-data test skipped (datasets " \
                  "live in ../shared/datasets or $STITCH_DATASETS)"

TEST(RealData, EurocMicroReadsWithCalibrationAndCameraGroundTruth) {
  const std::string path = DatasetPath("euroc/V1_01_easy_micro");
  SKIP_UNLESS_PRESENT(path);
  auto sequence = OpenDataset(path);
  EXPECT_EQ(sequence->size(), 95);
  EXPECT_EQ(sequence->camera().width(), 752);
  EXPECT_NEAR(sequence->camera().fx(), 458.654, 1e-9);
  EXPECT_TRUE(sequence->camera().HasDistortion());
  EXPECT_NEAR(sequence->nominal_fps(), 20.0, 0.05);
  // groundtruth_cam0.txt starts 1.05 s after the first image.
  EXPECT_GT(sequence->ground_truth().size(), 60u);
  SequenceFrame frame;
  int count = 0, with_truth = 0;
  while (sequence->Next(&frame)) {
    ASSERT_FALSE(frame.image.empty()) << frame.error;
    ++count;
    with_truth += sequence->ground_truth().PoseAt(frame.t_ns).has_value();
  }
  EXPECT_EQ(count, 95);
  EXPECT_NEAR(with_truth, 95 - 21, 2);
}

TEST(RealData, TumRpyReadsGrayscaleWithItsCalibration) {
  const std::string path = DatasetPath("tum/rgbd_dataset_freiburg1_rpy");
  SKIP_UNLESS_PRESENT(path);
  auto sequence = OpenDataset(path);
  EXPECT_EQ(sequence->size(), 723);
  EXPECT_NEAR(sequence->camera().fx(), 517.306408, 1e-9);
  EXPECT_NEAR(sequence->nominal_fps(), 30.0, 1.0);
  SequenceFrame frame;
  ASSERT_TRUE(sequence->Next(&frame));
  EXPECT_EQ(frame.image.cols, 640);
  EXPECT_EQ(frame.image.type(), CV_8UC1);
  // Ground truth (100 Hz) covers the frames.
  EXPECT_TRUE(sequence->ground_truth().PoseAt(frame.t_ns + 500'000'000));
}

}  // namespace
}  // namespace stitch
