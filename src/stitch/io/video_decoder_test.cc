#include "stitch/io/video_decoder.h"

#include <filesystem>
#include <fstream>
#include <memory>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "stitch/io/video_file_writer.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"
#include "stitch/util/rng.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

constexpr int kWidth = 320, kHeight = 240, kFrames = 12;

// A textured frame that moves with its index, spanning dark to bright grey.
cv::Mat Frame(int index) {
  cv::Mat image(kHeight, kWidth, CV_8U);
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) image.at<uint8_t>(y, x) = static_cast<uint8_t>((x + 3 * index) * 255 / kWidth);
  }
  cv::rectangle(image, cv::Rect(40 + 4 * index, 60, 60, 80), cv::Scalar(255), cv::FILLED);
  cv::rectangle(image, cv::Rect(200, 100 + 2 * index, 50, 50), cv::Scalar(0), cv::FILLED);
  return image;
}

// An H.264 clip of kFrames frames at 25 fps; null where GStreamer's x264enc is missing.
std::unique_ptr<std::string> WriteClip(const fs::path& path, int quantizer = H264FileOptions{}.quantizer) {
  try {
    H264FileOptions options{25.0};
    options.quantizer = quantizer;
    H264FileWriter writer(path.string(), kWidth, kHeight, options);
    for (int i = 0; i < kFrames; ++i) writer.Write(Frame(i));
    writer.Finish();
  } catch (const Error&) {
    return nullptr;
  }
  return std::make_unique<std::string>(path.string());
}

// The grey image is the decoded luma stretched from video range to full range: what OpenCV's
// reader gives through BGR, within a grey level or two (without the stretch, dark greys read
// 16 levels too bright and white 20 too dark).
TEST(VideoDecoder, GreyIsTheLumaInFullRangeAsOpenCvsReaderGivesIt) {
  testing::TempDir dir;
  const auto clip = WriteClip(dir / "clip.mp4");
  if (!clip) GTEST_SKIP() << "no H.264 encoder (gstreamer1.0-plugins-ugly)";
  VideoDecoder decoder(*clip);
  EXPECT_EQ(decoder.width(), kWidth);
  EXPECT_EQ(decoder.height(), kHeight);
  EXPECT_NEAR(decoder.fps(), 25.0, 1e-9);
  EXPECT_EQ(decoder.frame_count(), kFrames);
  cv::VideoCapture reference(*clip, cv::CAP_FFMPEG);
  ASSERT_TRUE(reference.isOpened());
  int frames = 0;
  cv::Mat gray, bgr, expected;
  int64_t t_ns = -1;
  while (decoder.Read(&gray, &t_ns)) {
    ASSERT_TRUE(reference.read(bgr));
    cv::cvtColor(bgr, expected, cv::COLOR_BGR2GRAY);
    ASSERT_EQ(gray.type(), CV_8UC1);
    ASSERT_EQ(gray.size(), expected.size());
    cv::Mat difference;
    cv::absdiff(gray, expected, difference);
    EXPECT_LT(cv::mean(difference)[0], 1.0) << "frame " << frames;
    double worst = 0;
    cv::minMaxLoc(difference, nullptr, &worst);
    EXPECT_LE(worst, 3) << "frame " << frames;
    EXPECT_EQ(t_ns, frames * 40'000'000LL) << "frame " << frames;  // the clip's own times, B-frames reordered
    ++frames;
  }
  EXPECT_EQ(frames, kFrames);
  EXPECT_FALSE(decoder.Read(&gray, &t_ns)) << "the end stays the end";
  EXPECT_EQ(decoder.skipped_packets() + decoder.skipped_frames(), 0);
}

TEST(VideoDecoder, SkipsFramesWithoutConvertingThem) {
  testing::TempDir dir;
  const auto clip = WriteClip(dir / "clip.mkv");
  if (!clip) GTEST_SKIP() << "no H.264 encoder (gstreamer1.0-plugins-ugly)";
  VideoDecoder decoder(*clip);
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(decoder.Skip());
  cv::Mat gray;
  int64_t t_ns = -1;
  ASSERT_TRUE(decoder.Read(&gray, &t_ns));
  EXPECT_EQ(t_ns, 5 * 40'000'000LL);
  EXPECT_LT(cv::norm(gray, Frame(5), cv::NORM_L1) / gray.total(), 3.0) << "frame 5 it is";
}

// Without its deblocking filter the decoder gives the same frames with their block edges left:
// on a coarsely quantized clip, other grey values, still the frame.
TEST(VideoDecoder, DeblockingCanBeSkipped) {
  testing::TempDir dir;
  const auto clip = WriteClip(dir / "coarse.mp4", 40);
  if (!clip) GTEST_SKIP() << "no H.264 encoder (gstreamer1.0-plugins-ugly)";
  VideoDecoder deblocked(*clip), blocky(*clip, /*skip_deblocking_from_pixels=*/0);
  EXPECT_TRUE(deblocked.deblocking());
  EXPECT_FALSE(blocky.deblocking());
  cv::Mat a, b;
  int64_t t_a = -1, t_b = -1;
  int frames = 0;
  double difference = 0;
  while (deblocked.Read(&a, &t_a)) {
    ASSERT_TRUE(blocky.Read(&b, &t_b));
    EXPECT_EQ(t_a, t_b);
    EXPECT_LT(cv::norm(b, Frame(frames), cv::NORM_L1) / b.total(), 8.0) << "frame " << frames;
    difference += cv::norm(a, b, cv::NORM_L1) / a.total();
    ++frames;
  }
  EXPECT_FALSE(blocky.Read(&b, &t_b));
  EXPECT_EQ(frames, kFrames);
  EXPECT_GT(difference / frames, 0.05) << "the filter was skipped";
}

// Hostile or damaged files: refused with a clear error, or read as far as they decode; never a
// crash (run under ASan in the sanitizer build).
TEST(VideoDecoder, DamagedFilesAreRefusedOrReadAsFarAsTheyGo) {
  testing::TempDir dir;
  {
    std::ofstream noise(dir / "noise.mp4", std::ios::binary);
    Rng rng(7);
    for (int i = 0; i < 100000; ++i) noise.put(static_cast<char>(rng.UniformInt(0, 255)));
  }
  try {
    VideoDecoder noise(dir / "noise.mp4");
    FAIL() << "noise opened as a video";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("noise.mp4"), std::string::npos) << e.what();
  }
  EXPECT_THROW(VideoDecoder(dir / "missing.mp4"), Error);

  const auto clip = WriteClip(dir / "clip.mkv");
  if (!clip) GTEST_SKIP() << "no H.264 encoder (gstreamer1.0-plugins-ugly)";
  std::string bytes;
  {
    std::ifstream in(*clip, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  ASSERT_GT(bytes.size(), 2000u);
  // Its middle overwritten with noise, and the file cut off two thirds in.
  std::string damaged = bytes;
  Rng rng(11);
  for (size_t i = damaged.size() / 3; i < damaged.size() / 2; ++i)
    damaged[i] = static_cast<char>(rng.UniformInt(0, 255));
  for (const auto& [name, content] :
       {std::make_pair("overwritten.mkv", damaged), std::make_pair("cut.mkv", bytes.substr(0, bytes.size() * 2 / 3))}) {
    const fs::path path = dir / name;
    std::ofstream(path, std::ios::binary) << content;
    try {
      VideoDecoder decoder(path.string());
      cv::Mat gray;
      int64_t t_ns = -1;
      int frames = 0;
      while (decoder.Read(&gray, &t_ns)) {
        ASSERT_EQ(gray.size(), cv::Size(kWidth, kHeight)) << name;
        ++frames;
      }
      EXPECT_LE(frames, kFrames) << name;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(name), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace stitch
