// Each reader on a small fixture written here (no real data in the repository).

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <memory>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "stitch/io/calibration.h"
#include "stitch/io/image_sequence.h"
#include "stitch/io/video_file_writer.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

constexpr int kWidth = 640, kHeight = 480;

cv::Mat TestImage(int index, int channels = 1) {
  cv::Mat image(kHeight, kWidth, channels == 1 ? CV_8U : CV_8UC3, cv::Scalar::all(40));
  cv::putText(image, std::to_string(index), cv::Point(40, 300), cv::FONT_HERSHEY_SIMPLEX, 6.0, cv::Scalar::all(220), 8);
  return image;
}

void WriteText(const fs::path& path, const std::string& text) {
  fs::create_directories(path.parent_path());
  std::ofstream(path) << text;
}

std::string PinholeYaml(int width = kWidth, int height = kHeight) {
  return "%YAML:1.0\nCamera.type: \"PinHole\"\nCamera.fx: 500\nCamera.fy: 500\nCamera.cx: 319.5\nCamera.cy: 239.5\n"
         "Camera.width: " +
         std::to_string(width) + "\nCamera.height: " + std::to_string(height) + "\n";
}

std::vector<SequenceFrame> ReadAll(ImageSequence& sequence) {
  std::vector<SequenceFrame> frames;
  SequenceFrame frame;
  while (sequence.Next(&frame)) frames.push_back(frame);
  return frames;
}

// Frame i shows the number i; compare pixels of what was read with what was written.
void ExpectShowsFrame(const SequenceFrame& frame, int index, double tolerance = 0.0) {
  ASSERT_FALSE(frame.image.empty()) << frame.error;
  ASSERT_EQ(frame.image.type(), CV_8UC1);
  EXPECT_LE(cv::norm(frame.image, TestImage(index), cv::NORM_L1) / frame.image.total(), tolerance);
}

TEST(Datasets, TumReadsListCalibrationAndGroundTruth) {
  testing::TempDir dir;
  const fs::path root = dir.path() / "rgbd_dataset_freiburg1_test";
  std::string list = "# color images\n# timestamp filename\n";
  std::string gt = "# ground truth\n";
  for (int i = 0; i < 3; ++i) {
    const std::string stamp = "1305031229." + std::to_string(100000 + i * 33333);
    fs::create_directories(root / "rgb");
    cv::imwrite((root / "rgb" / (stamp + ".png")).string(), TestImage(i, 3));  // colour, as TUM ships
    list += stamp + " rgb/" + stamp + ".png\n";
  }
  gt += "1305031229.0900 1 2 3 0 0 0 1\n1305031229.2000 2 2 3 0 0 0 1\n";
  WriteText(root / "rgb.txt", list);
  WriteText(root / "groundtruth.txt", gt);
  EXPECT_EQ(DetectDatasetKind(root.string()), "tum");
  // No camera.yaml: the folder name gives the published freiburg1 calibration.
  auto sequence = OpenDataset(root.string());
  EXPECT_NEAR(sequence->camera().fx(), 517.306408, 1e-9);
  EXPECT_EQ(sequence->size(), 3);
  const auto frames = ReadAll(*sequence);
  ASSERT_EQ(frames.size(), 3u);
  EXPECT_EQ(frames[1].t_ns, 1305031229133333000LL);
  ExpectShowsFrame(frames[2], 2, 1.0);
  EXPECT_EQ(sequence->ground_truth().size(), 2u);
  EXPECT_NEAR(sequence->nominal_fps(), 30.0, 0.01);
  // With camera.yaml, it wins.
  WriteText(root / "camera.yaml", PinholeYaml());
  EXPECT_DOUBLE_EQ(OpenDataset(root.string())->camera().fx(), 500);
}

// rgb.txt sorted by name (10.0 before 2.0) is played in time order; the ground truth is only what
// the played frames span.
TEST(Datasets, TumPlaysAListOutOfTimeOrderInTimeOrderAndClipsTheGroundTruth) {
  testing::TempDir dir;
  const fs::path root = dir.path() / "handheld";
  fs::create_directories(root / "rgb");
  std::string gt;
  for (int i = 0; i < 12; ++i) {
    const std::string stamp = std::to_string(i) + ".0";
    cv::imwrite((root / "rgb" / (stamp + ".png")).string(), TestImage(i));
    gt += std::to_string(i) + ".0 " + std::to_string(i) + " 0 0 0 0 0 1\n";
  }
  std::vector<std::string> names;
  for (int i = 0; i < 12; ++i) names.push_back(std::to_string(i) + ".0");
  std::sort(names.begin(), names.end());  // 0.0 1.0 10.0 11.0 2.0 ...
  std::string list;
  for (const auto& name : names) list += name + " rgb/" + name + ".png\n";
  WriteText(root / "rgb.txt", list);
  WriteText(root / "groundtruth.txt", gt);
  WriteText(root / "camera.yaml", PinholeYaml());
  SequenceOptions options;
  options.start_frame = 3;
  options.max_frames = 4;
  auto sequence = OpenDataset(root.string(), options);
  const auto frames = ReadAll(*sequence);
  ASSERT_EQ(frames.size(), 4u);
  for (int k = 0; k < 4; ++k) {
    EXPECT_EQ(frames[k].t_ns, (3 + k) * 1'000'000'000LL);
    ExpectShowsFrame(frames[k], 3 + k);
  }
  // Frames 3..6 and one sample on each side: 2..7.
  const auto& poses = sequence->ground_truth().poses();
  ASSERT_EQ(poses.size(), 6u);
  EXPECT_EQ(poses.front().t_ns, 2'000'000'000LL);
  EXPECT_EQ(poses.back().t_ns, 7'000'000'000LL);
}

TEST(Datasets, EurocReadsCsvSensorAndStateGroundTruth) {
  testing::TempDir dir;
  const fs::path root = dir.path() / "MH_test";
  const fs::path cam = root / "mav0" / "cam0";
  std::string csv = "#timestamp [ns],filename\n";
  for (int i = 0; i < 4; ++i) {
    const std::string stamp = std::to_string(1403636579763555584LL + i * 50000000LL);
    fs::create_directories(cam / "data");
    cv::imwrite((cam / "data" / (stamp + ".png")).string(), TestImage(i));
    csv += stamp + "," + stamp + ".png\r\n";  // EuRoC's csv files end lines with CRLF
  }
  WriteText(cam / "data.csv", csv);
  WriteText(cam / "sensor.yaml",
            "%YAML:1.0\nT_BS:\n  cols: 4\n  rows: 4\n  data: [0, -1, 0, 0.5, 1, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]\n"
            "resolution: [640, 480]\ncamera_model: pinhole\nintrinsics: [500, 500, 319.5, 239.5]\n"
            "distortion_model: radial-tangential\ndistortion_coefficients: [-0.01, 0.001, 0.0, 0.0]\n");
  WriteText(root / "mav0" / "state_groundtruth_estimate0" / "data.csv",
            "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []\n"
            "1403636579763555584,1.0,2.0,3.0,1,0,0,0,0,0,0,0,0,0,0,0,0\n"
            "1403636579913555584,1.0,2.0,3.0,1,0,0,0,0,0,0,0,0,0,0,0,0\n");
  EXPECT_EQ(DetectDatasetKind(root.string()), "euroc");
  auto sequence = OpenDataset(root.string());
  EXPECT_TRUE(sequence->camera().HasDistortion());
  const auto frames = ReadAll(*sequence);
  ASSERT_EQ(frames.size(), 4u);
  ExpectShowsFrame(frames[3], 3);
  EXPECT_EQ(frames[3].t_ns, 1403636579913555584LL);
  EXPECT_NEAR(sequence->nominal_fps(), 20.0, 1e-6);
  // Ground truth is the camera: body pose times T_BS (camera 0.5 m along body x).
  const auto pose = sequence->ground_truth().PoseAt(1403636579763555584LL);
  ASSERT_TRUE(pose);
  EXPECT_NEAR((pose->translation - Eigen::Vector3d(1.5, 2, 3)).norm(), 0, 1e-9);
  // Also opening mav0 directly, and start/max frames.
  SequenceOptions options;
  options.start_frame = 1;
  options.max_frames = 2;
  auto part = OpenDataset((root / "mav0").string(), options);
  const auto some = ReadAll(*part);
  ASSERT_EQ(some.size(), 2u);
  ExpectShowsFrame(some[0], 1);
  // `stitch eval --gt` reads the state ground truth directly, onto the camera with T_BS.
  const Trajectory gt = ReadGroundTruth((root / "mav0" / "state_groundtruth_estimate0" / "data.csv").string());
  ASSERT_EQ(gt.size(), 2u);
  EXPECT_NEAR((gt.poses()[0].world_from_cam.translation - Eigen::Vector3d(1.5, 2, 3)).norm(), 0, 1e-9);
}

TEST(Datasets, KittiReadsTimesCalibAndPoses) {
  testing::TempDir dir;
  const fs::path seq = dir.path() / "sequences" / "05";
  for (int i = 0; i < 3; ++i) {
    char name[16];
    std::snprintf(name, sizeof(name), "%06d.png", i);
    fs::create_directories(seq / "image_0");
    cv::imwrite((seq / "image_0" / name).string(), TestImage(i));
  }
  WriteText(seq / "times.txt", "0.000000e+00\n1.036000e-01\n2.072000e-01\n");
  WriteText(seq / "calib.txt", "P0: 80 0 47.5 0 0 80 31.5 0 0 0 1 0\n");
  WriteText(dir.path() / "poses" / "05.txt",
            "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 1.5\n1 0 0 0 0 1 0 0 0 0 1 3\n");
  EXPECT_EQ(DetectDatasetKind(seq.string()), "kitti");
  auto sequence = OpenDataset(seq.string());
  const auto frames = ReadAll(*sequence);
  ASSERT_EQ(frames.size(), 3u);
  EXPECT_EQ(frames[1].t_ns, 103600000);
  ExpectShowsFrame(frames[2], 2);
  ASSERT_EQ(sequence->ground_truth().size(), 3u);
  EXPECT_NEAR(sequence->ground_truth().poses()[2].world_from_cam.translation.z(), 3.0, 1e-12);
  // `stitch eval --gt poses/05.txt`: the times from sequences/05/times.txt, or given.
  const std::string poses = (dir.path() / "poses" / "05.txt").string();
  const Trajectory gt = ReadGroundTruth(poses);
  ASSERT_EQ(gt.size(), 3u);
  EXPECT_EQ(gt.poses()[1].t_ns, 103600000);
  EXPECT_NEAR(gt.poses()[1].world_from_cam.translation.z(), 1.5, 1e-12);
  WriteText(dir.path() / "other" / "times.txt", "0\n0.1\n");
  EXPECT_THROW(ReadGroundTruth(poses, (dir.path() / "other" / "times.txt").string()), Error);  // 3 poses, 2 times
  fs::copy_file(poses, dir.path() / "other" / "07.txt");
  EXPECT_THROW(ReadGroundTruth((dir.path() / "other" / "07.txt").string()), Error);  // no times anywhere
  EXPECT_EQ(ReadGroundTruth((dir.path() / "other" / "07.txt").string(), (seq / "times.txt").string()).size(), 3u);
}

TEST(Datasets, GroundTruthOfAnUnknownLayoutIsAClearError) {
  testing::TempDir dir;
  WriteText(dir / "tum.txt", "# time tx ty tz qx qy qz qw\n1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n");
  EXPECT_EQ(ReadGroundTruth(dir / "tum.txt").size(), 2u);
  WriteText(dir / "odd.txt", "1 2 3 4 5\n");
  try {
    ReadGroundTruth(dir / "odd.txt");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("not a ground truth stitch reads"), std::string::npos) << e.what();
  }
  WriteText(dir / "bent.txt", "2 0 0 0 0 1 0 0 0 0 1 0\n");
  EXPECT_THROW(ReadGroundTruth(dir / "bent.txt", dir / "tum.txt"), Error);  // not a rotation
  EXPECT_THROW(ReadGroundTruth(dir / "none.txt"), Error);
}

TEST(Datasets, ImageFolderNeedsCalibrationAndSortsByName) {
  testing::TempDir dir;
  const fs::path folder = dir.path() / "images";
  fs::create_directories(folder);
  for (int i = 0; i < 3; ++i) cv::imwrite((folder / ("frame_" + std::to_string(i) + ".png")).string(), TestImage(i));
  EXPECT_EQ(DetectDatasetKind(folder.string()), "folder");
  try {
    OpenDataset(folder.string());
    FAIL() << "a folder without calibration must be refused";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("--calib"), std::string::npos) << e.what();
  }
  WriteText(folder / "camera.yaml", PinholeYaml());
  SequenceOptions options;
  options.fps = 10;
  auto sequence = OpenDataset(folder.string(), options);
  const auto frames = ReadAll(*sequence);
  ASSERT_EQ(frames.size(), 3u);
  ExpectShowsFrame(frames[1], 1);
  EXPECT_EQ(frames[2].t_ns, 200000000);
}

TEST(Datasets, UnreadableImageIsReportedNotFatal) {
  testing::TempDir dir;
  const fs::path folder = dir.path() / "images";
  fs::create_directories(folder);
  for (int i = 0; i < 3; ++i) cv::imwrite((folder / (std::to_string(i) + ".png")).string(), TestImage(i));
  WriteText(folder / "1.png", "this is not a png");
  WriteText(folder / "camera.yaml", PinholeYaml());
  auto sequence = OpenDataset(folder.string());
  const auto frames = ReadAll(*sequence);
  ASSERT_EQ(frames.size(), 3u);
  EXPECT_TRUE(frames[1].image.empty());
  EXPECT_NE(frames[1].error.find("not a readable image"), std::string::npos) << frames[1].error;
  ExpectShowsFrame(frames[2], 2);
}

TEST(Datasets, CalibrationOfAnotherSizeIsRefused) {
  testing::TempDir dir;
  const fs::path folder = dir.path() / "images";
  fs::create_directories(folder);
  cv::imwrite((folder / "0.png").string(), TestImage(0));
  WriteText(folder / "camera.yaml", PinholeYaml(752, 480));
  try {
    OpenDataset(folder.string());
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("752x480"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("640x480"), std::string::npos) << e.what();
  }
}

TEST(Datasets, VideoFileIsReadFrameByFrame) {
  testing::TempDir dir;
  const std::string video = dir / "flight.avi";
  {
    cv::VideoWriter writer(video, cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), 25.0, cv::Size(kWidth, kHeight), true);
    ASSERT_TRUE(writer.isOpened());
    for (int i = 0; i < 5; ++i) writer.write(TestImage(i, 3));
  }
  EXPECT_EQ(DetectDatasetKind(video), "video");
  EXPECT_THROW(OpenDataset(video), Error);  // no calibration yet
  WriteText(dir / "flight.yaml", PinholeYaml());
  auto sequence = OpenDataset(video);
  EXPECT_NEAR(sequence->nominal_fps(), 25.0, 1e-6);
  const auto frames = ReadAll(*sequence);
  ASSERT_EQ(frames.size(), 5u);
  ExpectShowsFrame(frames[4], 4, 6.0);  // JPEG-compressed
  EXPECT_EQ(frames[4].t_ns, 160000000);
}

// An H.264 clip as an aircraft records one, at a rate that is not 30: read back with the clip's
// own times (also its last frames, which the decoder gives without one) and the ground truth
// beside it. Skipped where GStreamer's x264enc is missing (gstreamer1.0-plugins-ugly).
TEST(Datasets, H264VideoIsReadWithItsOwnTimesAndTheGroundTruthBesideIt) {
  testing::TempDir dir;
  const std::string video = dir / "flight.mp4";
  std::unique_ptr<H264FileWriter> writer;
  try {
    writer = std::make_unique<H264FileWriter>(video, kWidth, kHeight, H264FileOptions{25.0});
  } catch (const Error& e) {
    GTEST_SKIP() << e.what();
  }
  // Each frame a shade of its own (10 grey levels apart), so that a frame is told by its mean
  // whatever the codec's loss at edges.
  const auto shaded = [](int i) {
    cv::Mat image = TestImage(i);
    image.setTo(cv::Scalar::all(20 + 10 * i), image == 40);
    return image;
  };
  for (int i = 0; i < 20; ++i) writer->Write(shaded(i));
  EXPECT_FALSE(fs::exists(video)) << "named before it is whole";
  writer->Finish();
  EXPECT_TRUE(fs::exists(video));
  EXPECT_FALSE(fs::exists(video + ".part"));
  EXPECT_EQ(writer->frames_written(), 20);
  WriteText(dir / "flight.yaml", PinholeYaml());
  WriteText(dir / "flight.groundtruth.txt", "0.0 0 0 0 0 0 0 1\n1.0 1 0 0 0 0 0 1\n");
  auto sequence = OpenDataset(video);
  EXPECT_NEAR(sequence->nominal_fps(), 25.0, 1e-6);
  EXPECT_EQ(sequence->size(), 20);
  EXPECT_EQ(sequence->ground_truth().size(), 2u);
  const auto frames = ReadAll(*sequence);
  ASSERT_EQ(frames.size(), 20u);
  for (int i = 0; i < 20; ++i) {
    EXPECT_EQ(frames[i].t_ns, i * 40'000'000LL) << i;
    ASSERT_EQ(frames[i].image.type(), CV_8UC1);
    EXPECT_NEAR(cv::mean(frames[i].image)[0], cv::mean(shaded(i))[0], 3.0) << i;
  }
  // What the writer refuses: another container, an odd size, a frame that does not fit.
  EXPECT_THROW(H264FileWriter(dir / "flight.avi", kWidth, kHeight), Error);
  EXPECT_THROW(H264FileWriter(dir / "odd.mp4", 641, kHeight), Error);
  H264FileWriter other(dir / "other.mkv", kWidth, kHeight);
  EXPECT_THROW(other.Write(TestImage(0, 3)), Error);
  EXPECT_THROW(other.Write(cv::Mat(240, 320, CV_8UC1)), Error);
  other.Write(TestImage(0));
  other.Finish();
  EXPECT_EQ(ReadAll(*OpenDataset(dir / "other.mkv",
                                 [&] {
                                   SequenceOptions options;
                                   options.calibration_path = dir / "flight.yaml";
                                   return options;
                                 }()))
                .size(),
            1u);
}

// The writer's bit rate is the one asked (x264enc's own default capped every clip at 2 Mbit/s
// whatever its quantizer): noise, which no quantizer compresses, at 200 kbit/s and at the default.
TEST(Datasets, H264WriterKeepsToItsMostBitsPerSecond) {
  testing::TempDir dir;
  const auto write = [&](const std::string& name, int max_bitrate_kbps) {
    H264FileOptions options{25.0};
    options.max_bitrate_kbps = max_bitrate_kbps;
    H264FileWriter writer(dir / name, kWidth, kHeight, options);
    cv::Mat noise(kHeight, kWidth, CV_8UC1);
    cv::RNG rng(3);
    for (int i = 0; i < 25; ++i) {
      rng.fill(noise, cv::RNG::UNIFORM, 0, 256);
      writer.Write(noise);
    }
    writer.Finish();
    return static_cast<double>(fs::file_size(dir / name));
  };
  double capped = 0, realistic = 0;
  try {
    capped = write("capped.mp4", 200);
  } catch (const Error& e) {
    GTEST_SKIP() << e.what();
  }
  realistic = write("realistic.mp4", H264FileOptions{}.max_bitrate_kbps);
  EXPECT_LT(capped * 8 / 1000, 200 * 1.5) << "kbit in the second of frames";  // within the VBV's slack
  EXPECT_GT(realistic * 8 / 1000, 2048 * 2) << "above x264enc's own default cap";
  EXPECT_THROW(write("none.mp4", 10), Error);
}

TEST(Datasets, MissingOrUnknownPathsAreClearErrors) {
  testing::TempDir dir;
  EXPECT_THROW(DetectDatasetKind(dir / "nope"), Error);
  fs::create_directories(dir.path() / "empty");
  try {
    DetectDatasetKind(dir / "empty");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("not a dataset stitch knows"), std::string::npos);
  }
  WriteText(dir.path() / "notes.txt", "hello");
  EXPECT_THROW(DetectDatasetKind(dir / "notes.txt"), Error);
}

}  // namespace
}  // namespace stitch
