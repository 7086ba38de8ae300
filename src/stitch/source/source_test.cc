// What a run plays: the working size of large frames, and the source flags.

#include "stitch/source/source.h"

#include <cmath>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "stitch/config/ingest_options.h"
#include "stitch/geo/exiv2.h"
#include "stitch/io/calibration.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

TEST(WorkingSize, FramesWithinTheBudgetStayAsTheyAre) {
  EXPECT_EQ(WorkingSize(640, 480, 500000), std::make_pair(640, 480));
  EXPECT_EQ(WorkingSize(752, 480, 500000), std::make_pair(752, 480));
  EXPECT_EQ(WorkingSize(1241, 376, 500000), std::make_pair(1241, 376));  // KITTI
  EXPECT_EQ(WorkingSize(1920, 1080, 0), std::make_pair(1920, 1080));     // 0: as they come
}

TEST(WorkingSize, LargeFramesAreReducedWithinTheBudgetAndKeepTheirAspect) {
  for (const auto& [width, height] : {std::make_pair(1920, 1080), std::make_pair(3840, 2160),
                                      std::make_pair(4000, 3000), std::make_pair(1080, 1920)}) {
    const auto [w, h] = WorkingSize(width, height, 500000);
    EXPECT_LE(w * h, 500000) << width << "x" << height;
    EXPECT_GT(w * h, 480000) << width << "x" << height;  // not much below it either
    EXPECT_NEAR(static_cast<double>(h) / w, static_cast<double>(height) / width, 1.0 / w) << width << "x" << height;
  }
  EXPECT_EQ(WorkingSize(1920, 1080, 500000), std::make_pair(942, 530));
}

// The default budget is 960x540: an aircraft's 1080p and 4K frames reach it by exact halvings,
// the cheap step (a fractional one costs most of a reduction: features_benchmark's
// BM_ReduceToWorkingSize).
// Deblocking is skipped (auto) for the frames a halving reduces: 1080p and 4K by default, not
// 720p nor frames used as they come.
TEST(WorkingSize, DeblockingIsSkippedWhereAHalvingFollows) {
  SourceSpec spec;
  spec.max_working_pixels = IngestOptions{}.max_working_pixels;
  const int64_t from = SkipDeblockingFromPixels(spec);
  EXPECT_LE(from, 1920 * 1080);
  EXPECT_GT(from, 1280 * 720);
  spec.video_deblocking = "on";
  EXPECT_GT(SkipDeblockingFromPixels(spec), int64_t{3840} * 2160);
  spec.video_deblocking = "off";
  EXPECT_EQ(SkipDeblockingFromPixels(spec), 0);
  spec.video_deblocking = "auto";
  spec.max_working_pixels = 0;
  EXPECT_GT(SkipDeblockingFromPixels(spec), int64_t{3840} * 2160) << "frames as they come keep it";
  spec.video_deblocking = "sometimes";
  EXPECT_THROW(SkipDeblockingFromPixels(spec), Error);
}

TEST(WorkingSize, TheDefaultBudgetHalves1080pAnd4KExactly) {
  const int budget = IngestOptions{}.max_working_pixels;
  EXPECT_EQ(WorkingSize(1920, 1080, budget), std::make_pair(960, 540));
  EXPECT_EQ(WorkingSize(3840, 2160, budget), std::make_pair(960, 540));
  EXPECT_EQ(WorkingSize(752, 480, budget), std::make_pair(752, 480));  // 0.5 MP cameras as they come
  EXPECT_EQ(WorkingSize(1241, 376, budget), std::make_pair(1241, 376));
}

// A 1080p synthetic flight played at its working size: frames and camera agree, the ground truth
// is the camera's, and a point projects where the full-size camera puts it, scaled.
// The reduction by halvings then area averaging: exact block averages where the size halves the
// frame, and within a grey level of one area reduction from the full frame elsewhere.
TEST(WorkingSize, ReductionHalvesExactlyThenAveragesByArea) {
  cv::Mat frame(1080, 1920, CV_8UC1);
  for (int y = 0; y < frame.rows; ++y) {
    for (int x = 0; x < frame.cols; ++x) {
      frame.at<uint8_t>(y, x) = static_cast<uint8_t>(128 + 60 * std::sin(x * 0.05) * std::cos(y * 0.07) + (x + y) % 3);
    }
  }
  const cv::Mat half = ReduceToWorkingSize(frame, cv::Size(960, 540));
  ASSERT_EQ(half.size(), cv::Size(960, 540));
  for (const auto& [x, y] : std::vector<std::pair<int, int>>{{0, 0}, {311, 97}, {959, 539}}) {
    const int sum = frame.at<uint8_t>(2 * y, 2 * x) + frame.at<uint8_t>(2 * y, 2 * x + 1) +
                    frame.at<uint8_t>(2 * y + 1, 2 * x) + frame.at<uint8_t>(2 * y + 1, 2 * x + 1);
    EXPECT_NEAR(half.at<uint8_t>(y, x), sum / 4.0, 0.5) << x << "," << y;
  }
  const cv::Mat reduced = ReduceToWorkingSize(frame, cv::Size(942, 530));
  ASSERT_EQ(reduced.size(), cv::Size(942, 530));
  cv::Mat in_one_step, difference;
  cv::resize(frame, in_one_step, cv::Size(942, 530), 0, 0, cv::INTER_AREA);
  cv::absdiff(reduced, in_one_step, difference);
  EXPECT_LT(cv::mean(difference)[0], 1.0);
  // A frame of the size already: as it is.
  EXPECT_EQ(ReduceToWorkingSize(half, half.size()).data, half.data);
}

TEST(WorkingSize, ALargeCamerasFramesArePlayedReducedWithTheirCamera) {
  SourceSpec spec;
  spec.synthetic.width = 1920;
  spec.synthetic.height = 1080;
  spec.synthetic.focal_px = 1350;
  spec.failures = "none";
  spec.max_frames = 2;
  spec.max_working_pixels = 500000;
  FailureSchedule spoil;
  auto reduced = OpenSource(spec, &spoil);
  EXPECT_EQ(reduced->camera().width(), 942);
  EXPECT_EQ(reduced->camera().height(), 530);
  EXPECT_NE(reduced->description().find("reduced to 942x530"), std::string::npos) << reduced->description();
  SequenceFrame frame;
  ASSERT_TRUE(reduced->Next(&frame));
  EXPECT_EQ(frame.image.cols, 942);
  EXPECT_EQ(frame.image.rows, 530);
  EXPECT_EQ(SummarizeSource(spec).camera.width(), 942);

  spec.max_working_pixels = 0;
  auto full = OpenSource(spec, &spoil);
  EXPECT_EQ(full->camera().width(), 1920);
  ASSERT_EQ(full->ground_truth().size(), reduced->ground_truth().size());
  const Eigen::Vector3d point(1.5, -0.7, 12.0);
  const Eigen::Vector2d at_full = *full->camera().Project(point), at_working = *reduced->camera().Project(point);
  EXPECT_NEAR(at_working.x() + 0.5, (at_full.x() + 0.5) * 942.0 / 1920.0, 1e-9);
  EXPECT_NEAR(at_working.y() + 0.5, (at_full.y() + 0.5) * 530.0 / 1080.0, 1e-9);
}

// A program handing its source on to another (stitch bench --realtime to stitch run): the flags
// read back give the same spec, and only what differs from the defaults is passed.
TEST(SourceArguments, TheFlagsHandOnWhatWasGivenAndNothingElse) {
  const char* given[] = {"prog", "--dataset", "/data/tum", "--max-frames", "300", "--start-frame", "8"};
  SourceSpec spec;
  ArgParser args("prog", "");
  AddSourceOptions(&args, &spec);
  ASSERT_TRUE(args.Parse(7, const_cast<char**>(given)));
  const std::vector<std::string> handed = SourceArguments(spec);
  EXPECT_EQ(handed, (std::vector<std::string>{"--dataset", "/data/tum", "--max-frames", "300", "--start-frame", "8"}));
  // Read back by the other program: the same spec.
  std::vector<const char*> again{"other"};
  for (const std::string& a : handed) again.push_back(a.c_str());
  SourceSpec received;
  ArgParser other("other", "");
  AddSourceOptions(&other, &received);
  ASSERT_TRUE(other.Parse(static_cast<int>(again.size()), const_cast<char**>(again.data())));
  EXPECT_EQ(received.dataset_path, spec.dataset_path);
  EXPECT_EQ(received.max_frames, 300);
  EXPECT_EQ(received.start_frame, 8);
  EXPECT_EQ(received.failures, SourceSpec().failures);
  // Only the flags asked for; none for a spec left at its defaults.
  EXPECT_EQ(SourceArguments(spec, kMaxFramesFlag), (std::vector<std::string>{"--max-frames", "300"}));
  EXPECT_TRUE(SourceArguments(SourceSpec()).empty());
  SourceSpec live;
  live.live_uri = "filesrc location=f.mp4 ! decodebin ! appsink";
  live.live_clock = "wall";
  EXPECT_EQ(SourceArguments(live), (std::vector<std::string>{"--live", live.live_uri, "--live-clock", "wall"}));
}

// What tracker.tracking.rolling_shutter_line_us -1 becomes: the synthetic camera's readout per
// row of the working frames, or a rendered folder's calibration's (Camera.line_delay_us).
TEST(SourceLineDelay, IsTheSyntheticCamerasOrTheCalibrationBesideTheData) {
  SourceSpec spec;
  EXPECT_EQ(SourceLineDelayUs(spec, spec.synthetic.MakeCamera()), 0);
  spec.synthetic.camera.rolling_shutter_line_us = 40;
  EXPECT_EQ(SourceLineDelayUs(spec, spec.synthetic.MakeCamera()), 40);
  EXPECT_EQ(SourceLineDelayUs(spec, spec.synthetic.MakeCamera().Resized(320, 240)), 80) << "half the rows";
  testing::TempDir dir;
  spec.dataset_path = dir / "frames";
  std::filesystem::create_directories(spec.dataset_path);
  const Camera camera = Camera::Pinhole(640, 480, 450, 450, 319.5, 239.5);
  EXPECT_EQ(SourceLineDelayUs(spec, camera), 0) << "no calibration states one";
  SaveCalibration(camera, spec.dataset_path + "/camera.yaml", 25);
  EXPECT_EQ(SourceLineDelayUs(spec, camera), 25);
}

}  // namespace
}  // namespace stitch

namespace stitch {
namespace {

STITCH_EXIV2_BEGIN
// Writes a DJI's gimbal pitch into a photo's XMP.
void SetGimbalPitch(const std::string& path, const std::string& pitch_deg) {
  Exiv2::Image::AutoPtr image = Exiv2::ImageFactory::open(path);
  image->readMetadata();
  Exiv2::XmpProperties::registerNs("http://www.dji.com/drone-dji/1.0/", "drone-dji");
  image->xmpData()["Xmp.drone-dji.GimbalPitchDegree"] = pitch_deg;
  image->writeMetadata();
}
STITCH_EXIV2_END

// Where the source states its camera's mount: the synthetic flight's nadir camera; a folder of
// photos whose XMP says the gimbal looked straight down (ExifGps.*); nothing else.
TEST(SourceCameraUpAxis, IsTheSyntheticNadirCameraOrThePhotosGimbal) {
  SourceSpec spec;
  EXPECT_EQ(SourceCameraUpAxis(spec), "-z");
  spec.synthetic.flight.camera_pitch_deg = 45;
  EXPECT_EQ(SourceCameraUpAxis(spec), "");
  testing::TempDir dir;
  spec.dataset_path = dir / "photos";
  std::filesystem::create_directories(spec.dataset_path);
  EXPECT_EQ(SourceCameraUpAxis(spec), "") << "a folder without photos";
  for (int i = 0; i < 3; ++i) {
    cv::imwrite(spec.dataset_path + "/" + std::to_string(i) + ".jpg", cv::Mat(48, 64, CV_8UC1, cv::Scalar(100 + i)));
  }
  EXPECT_EQ(SourceCameraUpAxis(spec), "") << "photos that state no gimbal";
  for (int i = 0; i < 3; ++i) SetGimbalPitch(spec.dataset_path + "/" + std::to_string(i) + ".jpg", "-90.0");
  EXPECT_EQ(SourceCameraUpAxis(spec), "-z") << "a drone's photos, its gimbal straight down";
  SetGimbalPitch(spec.dataset_path + "/1.jpg", "-45.0");
  EXPECT_EQ(SourceCameraUpAxis(spec), "") << "one of them tilted";
  spec.dataset_path = dir / "video.mp4";
  EXPECT_EQ(SourceCameraUpAxis(spec), "");
  spec.dataset_path.clear();
  spec.live_uri = "/dev/video0";
  EXPECT_EQ(SourceCameraUpAxis(spec), "");
}

// A dataset's fixes: its gnss.csv, else a DJI track beside a video (FILE.SRT), else none.
TEST(DatasetGnss, IsTheGnssCsvElseTheDjiTrackBesideTheVideo) {
  testing::TempDir dir;
  const std::string video = dir / "DJI_0007.MP4";
  EXPECT_TRUE(DatasetGnss(video).fixes.empty());
  {
    std::ofstream srt(dir / "DJI_0007.SRT");
    srt << "1\n00:00:00,500 --> 00:00:00,533\n[latitude: 47.5] [longitude: 8.5] [rel_alt: 1 abs_alt: 420]\n";
  }
  GnssTrack track = DatasetGnss(video);
  ASSERT_EQ(track.fixes.size(), 1u);
  EXPECT_EQ(track.fixes[0].t_ns, 500'000'000);
  GnssTrack csv;
  csv.source = "a receiver";
  csv.fixes.push_back(track.fixes[0]);
  csv.fixes[0].t_ns = 7;
  WriteGnssCsv(GnssFileBeside(video), csv);
  track = DatasetGnss(video);
  ASSERT_EQ(track.fixes.size(), 1u);
  EXPECT_EQ(track.fixes[0].t_ns, 7) << "gnss.csv comes first";
  EXPECT_TRUE(DatasetGnss(dir.path().string()).fixes.empty()) << "a folder without gnss.csv";
  EXPECT_TRUE(DatasetGnss("").fixes.empty());
}

}  // namespace
}  // namespace stitch
