// A live source through a GStreamer pipeline that plays an image folder at its frame rate
// (multifilesrc ! pngdec ! appsink sync=true), as a camera would give it. Skipped where GStreamer's
// plugins are not installed (gstreamer1.0-plugins-base and -good).

#include "stitch/io/live_capture.h"

#include <cmath>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "stitch/io/calibration.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

// `count` noise images 00000.png... and a calibration, in `dir`; the pipeline that plays them at `fps`.
std::string WriteFramesAndPipeline(const testing::TempDir& dir, int count, int fps) {
  Rng rng(3);
  for (int i = 0; i < count; ++i) {
    cv::Mat image(120, 160, CV_8UC1);
    for (int r = 0; r < image.rows; ++r)
      for (int c = 0; c < image.cols; ++c) image.at<uint8_t>(r, c) = static_cast<uint8_t>(rng.Uniform(0, 255));
    char name[32];
    std::snprintf(name, sizeof(name), "%05d.png", i);
    cv::imwrite(dir / name, image);
  }
  SaveCalibration(Camera::Pinhole(160, 120, 150, 150, 79.5, 59.5), dir / "camera.yaml");
  return "multifilesrc location=" + (dir / "%05d.png") + " index=0 caps=image/png,framerate=" + std::to_string(fps) +
         "/1 ! pngdec ! videoconvert ! appsink sync=true";
}

bool GStreamerPlays(const std::string& pipeline) {
  cv::VideoCapture probe(pipeline, cv::CAP_GSTREAMER);
  cv::Mat frame;
  return probe.isOpened() && probe.read(frame) && !frame.empty();
}

// A test that plays a folder of frames through a pipeline: the folder, and the options that
// name its calibration.
class LivePipeline : public ::testing::Test {
 protected:
  static constexpr const char* kCannotPlay = "GStreamer cannot play PNG files here (gstreamer1.0-plugins-good)";
  // Writes `count` frames played at `fps`; their pipeline, or "" where GStreamer cannot play it.
  std::string Pipeline(int count, int fps) {
    const std::string pipeline = WriteFramesAndPipeline(dir, count, fps);
    options.calibration_path = dir / "camera.yaml";
    return GStreamerPlays(pipeline) ? pipeline : "";
  }
  testing::TempDir dir;
  LiveCaptureOptions options;
};

TEST(LiveCapture, TellsTheKindOfSourceFromItsName) {
  EXPECT_EQ(LiveSourceKind("/dev/video0"), "v4l2");
  EXPECT_EQ(LiveSourceKind("v4l2:/dev/video2"), "v4l2");
  EXPECT_EQ(LiveSourceKind("videotestsrc ! appsink"), "gstreamer");
  EXPECT_EQ(LiveSourceKind("gst:videotestsrc"), "gstreamer");
  EXPECT_EQ(LiveSourceKind("rtsp://192.168.1.10:8554/cam"), "stream");
  EXPECT_EQ(LiveSourceKind("udp://0.0.0.0:5600"), "stream");
  EXPECT_THROW(LiveSourceKind("flight.mp4"), Error);
  EXPECT_THROW(LiveSourceKind(""), Error);
}

TEST(LiveCapture, AFileThroughAPipelineKeepsItsOwnClockAndACameraTheWallClock) {
  EXPECT_EQ(LiveClock("filesrc location=f.mp4 ! decodebin ! appsink", "auto"), "stream");
  EXPECT_EQ(LiveClock("gst: multifilesrc location=%05d.png ! pngdec ! appsink", "auto"), "stream");
  EXPECT_EQ(LiveClock("uridecodebin uri=file:///f.mp4 ! appsink", "auto"), "stream");
  EXPECT_EQ(LiveClock("v4l2src ! videoconvert ! appsink", "auto"), "wall");
  EXPECT_EQ(LiveClock("udpsrc port=5600 ! decodebin ! appsink", "auto"), "wall");
  EXPECT_EQ(LiveClock("/dev/video0", "auto"), "wall");
  EXPECT_EQ(LiveClock("filesrc location=f.mp4 ! decodebin ! appsink", "wall"), "wall");
  EXPECT_EQ(LiveClock("v4l2src ! appsink", "stream"), "stream");
  EXPECT_THROW(LiveClock("rtsp://camera/stream", "stream"), Error);  // no pipeline to ask
  EXPECT_THROW(LiveClock("v4l2src ! appsink", "gps"), Error);
}

TEST(LiveCapture, RefusesASourceItCannotOpenOrOneWithoutCalibration) {
  testing::TempDir dir;
  SaveCalibration(Camera::Pinhole(160, 120, 150, 150, 79.5, 59.5), dir / "camera.yaml");
  LiveCaptureOptions options;
  EXPECT_THROW(LiveCapture("/dev/video0", options), Error) << "no calibration";
  options.calibration_path = dir / "camera.yaml";
  EXPECT_THROW(LiveCapture("/dev/video-none", options), Error);
  EXPECT_THROW(LiveCapture("no-such-element-anywhere ! appsink", options), Error);
}

TEST_F(LivePipeline, PlaysAPipelineAtItsRateAndKeepsOnlyTheNewestFrame) {
  const std::string pipeline = Pipeline(40, 20);
  if (pipeline.empty()) GTEST_SKIP() << kCannotPlay;
  options.clock = "wall";
  LiveCapture live(pipeline, options);
  EXPECT_TRUE(live.live());
  EXPECT_EQ(live.size(), -1);
  EXPECT_EQ(live.camera().width(), 160);
  EXPECT_DOUBLE_EQ(live.nominal_fps(), 20);
  SequenceFrame first, second, third;
  ASSERT_TRUE(live.Next(&first));
  ASSERT_TRUE(live.Next(&second));
  EXPECT_EQ(first.index, 0);
  EXPECT_EQ(second.index, 1);
  EXPECT_EQ(second.image.type(), CV_8UC1);
  EXPECT_EQ(second.image.cols, 160);
  // A consumer 400 ms late (8 frames at 20 fps) gets the newest frame; the ones between are
  // counted as dropped, not queued.
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  ASSERT_TRUE(live.Next(&third));
  EXPECT_EQ(third.index, 2);
  EXPECT_GE(live.dropped_at_source(), 4);
  // Capture times on the wall clock, in order, as far apart as the frames were.
  EXPECT_GT(second.t_ns, first.t_ns);
  EXPECT_GT(third.t_ns - second.t_ns, 250'000'000);
  // Played to the end: every frame was either taken or counted as dropped.
  int taken = 3;
  SequenceFrame frame;
  while (live.Next(&frame)) ++taken;
  EXPECT_EQ(taken + live.dropped_at_source(), 40);
}

// Played on the stream's clock, the frames keep their times in the clip (frame i at i / 20 s),
// whole frames apart also where some were taken late.
TEST_F(LivePipeline, OnTheStreamClockFramesKeepTheirTimesInTheClip) {
  const std::string pipeline = Pipeline(12, 20);
  if (pipeline.empty()) GTEST_SKIP() << kCannotPlay;
  LiveCapture live(pipeline, options);  // auto: a pipeline reading files
  EXPECT_NE(live.description().find("stream clock"), std::string::npos) << live.description();
  std::vector<int64_t> times;
  SequenceFrame frame;
  while (live.Next(&frame)) times.push_back(frame.t_ns);
  ASSERT_GE(times.size(), 6u);
  // Every time on the clip's frame grid, in order, whole frames apart. (Which frame a time names
  // is asked as the frame leaves the pipeline: on a loaded machine, a sanitizer's, it was up to
  // three frames late.)
  for (size_t i = 0; i < times.size(); ++i) {
    const double frames = times[i] / 50e6;
    EXPECT_NEAR(frames, std::round(frames), 0.04) << times[i];
    if (i > 0) EXPECT_GT(times[i], times[i - 1]);
  }
}

TEST_F(LivePipeline, StopsAfterMaxFrames) {
  const std::string pipeline = Pipeline(10, 50);
  if (pipeline.empty()) GTEST_SKIP() << kCannotPlay;
  options.max_frames = 3;
  LiveCapture live(pipeline, options);
  SequenceFrame frame;
  int taken = 0;
  while (live.Next(&frame)) ++taken;
  EXPECT_EQ(taken, 3);
}

}  // namespace
}  // namespace stitch
