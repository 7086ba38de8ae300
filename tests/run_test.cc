// `stitch run` end to end: the real service processes over UDP multicast.

#include <signal.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/videoio.hpp>

#include "stitch/io/ply.h"
#include "stitch/io/trajectory.h"
#include "stitch/records/frame_record.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/child_process.h"
#include "tests/test_process.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

using testing::Bin;
using testing::RunProgram;

using testing::ReadJson;
const std::string kShortFlight = testing::ShortFlightConfig();

TEST(StitchRun, TracksAShortFlightWithTheServicesAsProcesses) {
  testing::TempDir dir;
  const std::string out = dir / "run";
  const auto result =
      RunProgram({Bin("stitch"), "run", "--config", kShortFlight, "--out", out, "--failures", "none"}, 180);
  ASSERT_EQ(result.exit_code, 0) << result.output;
  for (const char* file :
       {"trajectory.tum",   "map.ply",         "report.json",     "trajectory.png",  "frames.tsv",
        "poses.tsv",        "keyframes.tsv",   "groundtruth.tum", "config.yaml",     "run.json",
        "logs/tracker.log", "logs/ingest.log", "logs/mapper.log", "logs/merger.log", "submaps.tsv",
        "graph.dot",        "graph.png",       "merge_log.tsv",   "retrieval.tsv",   "keyframes_merged.tsv"}) {
    EXPECT_TRUE(fs::exists(fs::path(out) / file)) << file;
  }
  const auto report = ReadJson(out + "/report.json");
  for (const char* key : {"frames_total", "frames_localized", "completeness", "keyframes", "submaps", "submaps_merged",
                          "ate_rmse_m", "tracking_ms_median"}) {
    EXPECT_TRUE(report.contains(key)) << key;
  }
  EXPECT_EQ(report["frames_total"], 60);
  // Every frame went through ingest, the bus and the tracker process, once.
  const auto records = ReadFrameRecords(out + "/frames.tsv");
  ASSERT_EQ(records.size(), 60u);
  for (int i = 0; i < 60; ++i) EXPECT_EQ(records[i].frame_index, i);
  EXPECT_EQ(Trajectory::ReadTum(out + "/groundtruth.tum").size(), 60u);
  // The trajectory agrees with the ground truth: all but the first frames posed, ATE well under
  // 1% of the 69 m strip.
  EXPECT_GE(report["frames_localized"].get<int>(), 56) << result.output;
  ASSERT_FALSE(report["ate_rmse_m"].is_null());
  EXPECT_LT(report["ate_rmse_m"].get<double>(), 0.3);
  EXPECT_GT(report["keyframes"].get<int>(), 3);
  // The mapper's map made it to disk.
  EXPECT_GT(ReadPly(out + "/map.ply").size(), 500u);
  // The summary says what happened.
  EXPECT_NE(result.output.find("frames localized"), std::string::npos) << result.output;
  // `stitch eval` rebuilds the same report from the folder.
  const auto eval = RunProgram({Bin("stitch"), "eval", out});
  EXPECT_EQ(eval.exit_code, 0) << eval.output;
  EXPECT_EQ(ReadJson(out + "/report.json")["frames_total"], 60);
}

TEST(StitchRun, CtrlCStopsEverythingAndStillWritesTheOutputs) {
  testing::TempDir dir;
  const std::string out = dir / "run";
  std::ofstream(dir / "long.yaml") << "synthetic:\n  flight:\n    num_frames: 100000\n    num_strips: 1\n"
                                      "    strip_length_m: 60\n  world:\n    num_buildings: 4\n";
  const auto result = RunProgram({Bin("stitch"), "run", "--config", dir / "long.yaml", "--out", out}, 60, 4, SIGINT);
  EXPECT_EQ(result.exit_code, 130) << result.output;
  EXPECT_TRUE(fs::exists(out + "/report.json")) << result.output;
  EXPECT_EQ(ReadJson(out + "/run.json")["interrupted"], true);
  // No service is left running on this run's bus.
  const auto leftover = RunProgram({"/usr/bin/pgrep", "-f", "--", "--record " + out + "/frames.tsv"});
  EXPECT_NE(leftover.exit_code, 0) << "a tracker survived:\n" << leftover.output;
}

TEST(StitchRun, BadInputsGiveAClearErrorAndANonZeroExit) {
  testing::TempDir dir;
  struct Case {
    std::vector<std::string> args;
    std::string expected;
  };
  std::ofstream(dir / "typo.yaml") << "ingest:\n  pacnig: realtime\n";
  std::ofstream(dir / "calib.yaml")
      << "Camera.fx: 500\nCamera.fy: 500\nCamera.cx: 320\nCamera.cy: 240\nCamera.width: 752\nCamera.height: 480\n";
  fs::create_directories(dir.path() / "images");
  std::ofstream(dir / "images/0.png") << "not a png";
  const std::vector<Case> cases = {
      {{Bin("stitch"), "run", "--dataset", dir / "missing"}, "no such file or folder"},
      {{Bin("stitch"), "run", "--config", dir / "typo.yaml"}, "pacnig"},
      {{Bin("stitch"), "run", "--config", dir / "nothere.yaml"}, "no such file"},
      {{Bin("stitch"), "run", "--failures", "12:x"}, "FRAME:LENGTH"},
      {{Bin("stitch"), "run", "--on-loss", "panic"}, "on_loss"},
      {{Bin("stitch"), "run", "--dataset", dir / "images", "--calib", dir / "calib.yaml"}, "first image"},
      {{Bin("stitch"), "run", "--bogus"}, "unknown option"},
      {{Bin("stitch"), "eval"}, "nothing to evaluate"},
      {{Bin("stitch"), "eval", dir.path().string()}, "run.json"},
      {{Bin("stitch"), "frobnicate"}, "unknown command"},
      {{Bin("stitch-ingest"), "--pacing", "warp"}, "pacing"},
      {{Bin("stitch-ingest"), "--agent", "uav 0"}, "agent name"},
      {{Bin("stitch-tracker"), "--config", dir / "typo.yaml"}, "pacnig"},
      {{Bin("stitch-link"), "--peer", "nowhere"}, "ADDRESS:PORT"},
      {{Bin("stitch-link"), "--loss", "2"}, "link.loss"},
      {{Bin("stitch"), "run", "--link-loss", "0.1"}, "need --link"},
      {{Bin("stitch"), "run", "--live", "flight.mp4", "--calib", dir / "calib.yaml"}, "GStreamer pipeline"},
      {{Bin("stitch"), "run", "--live", "/dev/video0"}, "--calib"},
      {{Bin("stitch-ingest"), "--live", "/dev/video-none", "--calib", dir / "calib.yaml", "--lcm-url", "memq://",
        "--set", "ingest.wait_for_tracker_s=0"},
       "cannot open it"},
  };
  for (const auto& c : cases) {
    const auto result = RunProgram(c.args, 30);
    std::string line;
    for (const auto& a : c.args) line += a + " ";
    EXPECT_NE(result.exit_code, 0) << line << "\n" << result.output;
    EXPECT_NE(result.exit_code, 128 + SIGSEGV) << line;
    EXPECT_NE(result.output.find(c.expected), std::string::npos) << line << "\nsaid:\n" << result.output;
  }
}

TEST(StitchRun, EveryCommandHasHelp) {
  for (const std::vector<std::string>& args : std::vector<std::vector<std::string>>{{Bin("stitch"), "--help"},
                                                                                    {Bin("stitch"), "run", "--help"},
                                                                                    {Bin("stitch"), "eval", "--help"},
                                                                                    {Bin("stitch"), "render", "--help"},
                                                                                    {Bin("stitch"), "config", "--help"},
                                                                                    {Bin("stitch-ingest"), "--help"},
                                                                                    {Bin("stitch-tracker"), "--help"},
                                                                                    {Bin("stitch"), "link", "--help"},
                                                                                    {Bin("stitch-link"), "--help"}}) {
    const auto result = RunProgram(args, 10);
    EXPECT_EQ(result.exit_code, 0) << args[0] << " " << args[1];
    EXPECT_NE(result.output.find("usage:"), std::string::npos) << result.output;
  }
}

TEST(StitchRender, WritesAFolderThatRunsAsADataset) {
  testing::TempDir dir;
  const std::string images = dir / "flight";
  const auto render =
      RunProgram({Bin("stitch"), "render", "--config", kShortFlight, "--out", images, "--max-frames", "12"}, 60);
  ASSERT_EQ(render.exit_code, 0) << render.output;
  EXPECT_TRUE(fs::exists(images + "/camera.yaml"));
  EXPECT_EQ(Trajectory::ReadTum(images + "/groundtruth.txt").size(), 12u);
  const auto run = RunProgram({Bin("stitch"), "run", "--dataset", images, "--out", dir / "run"}, 60);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_EQ(ReadJson(dir / "run/report.json")["frames_total"], 12);
  EXPECT_EQ(ReadJson(dir / "run/report.json")["has_ground_truth"], true);
}

// A live camera end to end: a GStreamer pipeline plays a rendered flight at its 20 fps (as a
// camera gives frames, whatever the tracker does) into `stitch run --live`.
TEST(StitchRun, TracksALiveGStreamerSource) {
  testing::TempDir dir;
  const std::string images = dir / "flight";
  const auto render = RunProgram(
      {Bin("stitch"), "render", "--config", kShortFlight, "--out", images, "--failures", "none", "--max-frames", "60"},
      60);
  ASSERT_EQ(render.exit_code, 0) << render.output;
  // multifilesrc reads numbered files: the frames in time order as 00000.png, 00001.png, ...
  std::vector<fs::path> frames;
  for (const auto& entry : fs::directory_iterator(images)) {
    if (entry.path().extension() == ".png") frames.push_back(entry.path());
  }
  std::sort(frames.begin(), frames.end(),
            [](const fs::path& a, const fs::path& b) { return std::stod(a.stem()) < std::stod(b.stem()); });
  ASSERT_EQ(frames.size(), 60u);
  const std::string numbered = dir / "numbered";
  fs::create_directories(numbered);
  for (size_t i = 0; i < frames.size(); ++i) {
    char name[32];
    std::snprintf(name, sizeof(name), "%05zu.png", i);
    fs::rename(frames[i], fs::path(numbered) / name);
  }
  const std::string pipeline =
      "multifilesrc location=" + numbered +
      "/%05d.png index=0 caps=image/png,framerate=20/1 ! pngdec ! videoconvert ! appsink sync=true";
  {
    cv::VideoCapture probe(pipeline, cv::CAP_GSTREAMER);
    cv::Mat frame;
    if (!probe.isOpened() || !probe.read(frame)) {
      GTEST_SKIP() << "GStreamer cannot play PNG files here (install gstreamer1.0-plugins-base and -good)";
    }
  }
  const std::string out = dir / "run";
  const auto run =
      RunProgram({Bin("stitch"), "run", "--live", pipeline, "--calib", images + "/camera.yaml", "--out", out}, 120);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("live pacing"), std::string::npos) << run.output;
  const auto report = ReadJson(out + "/report.json");
  EXPECT_EQ(report["run"]["pacing"], "live");
  // The tracker heard of nearly every frame (a frame captured while the services started may be
  // replaced by a newer one), in order, and posed most of them in one map.
  const auto records = ReadFrameRecords(out + "/frames.tsv");
  EXPECT_GE(records.size(), 50u);
  for (size_t i = 1; i < records.size(); ++i) EXPECT_GT(records[i].frame_index, records[i - 1].frame_index);
  EXPECT_GE(report["frames_localized"].get<int>(), 40) << run.output;
  EXPECT_GT(report["keyframes"].get<int>(), 3);
  EXPECT_GT(ReadPly(out + "/map.ply").size(), 500u);
  // Capture times on the wall clock, 50 ms apart on average.
  const double span_s = (records.back().t_ns - records.front().t_ns) * 1e-9;
  EXPECT_GT(span_s, 0.035 * static_cast<double>(records.size() - 1));
  EXPECT_GT(records.front().t_ns, 1'600'000'000'000'000'000);  // after 2020: the wall clock
}

// The processes whose parent is `parent` (from /proc).
std::vector<pid_t> ChildrenOf(pid_t parent) {
  std::vector<pid_t> children;
  for (const auto& entry : fs::directory_iterator("/proc")) {
    const std::string name = entry.path().filename().string();
    if (name.find_first_not_of("0123456789") != std::string::npos) continue;
    std::ifstream stat(entry.path() / "stat");
    std::string line;
    if (!std::getline(stat, line) || line.rfind(')') == std::string::npos) continue;
    std::istringstream fields(line.substr(line.rfind(')') + 2));
    char state = 0;
    pid_t ppid = 0;
    if (fields >> state >> ppid && ppid == parent) children.push_back(std::stoi(name));
  }
  return children;
}

// Running: /proc has it and it is not a zombie waiting to be reaped.
bool Running(pid_t pid) {
  std::ifstream stat("/proc/" + std::to_string(pid) + "/stat");
  std::string line;
  if (!std::getline(stat, line) || line.rfind(')') == std::string::npos) return false;
  return line[line.rfind(')') + 2] != 'Z';
}

// The security issue's row: SIGKILL of the `stitch run` launcher left tracker, mapper and merger
// running as orphans.
TEST(StitchRun, ItsServicesEndWhenTheLauncherIsKilled) {
  testing::TempDir dir;
  ChildProcess launcher("run", Bin("stitch"), {"run", "--quiet", "--out", dir / "run"}, dir / "run.log");
  std::vector<pid_t> services;
  for (int i = 0; i < 600 && services.size() < 4; ++i) {  // ingest, tracker, mapper, merger
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    services = ChildrenOf(launcher.pid());
  }
  ASSERT_GE(services.size(), 4u) << launcher.LogTail(10);
  ASSERT_EQ(kill(launcher.pid(), SIGKILL), 0);
  EXPECT_EQ(launcher.Terminate(std::chrono::milliseconds(5000)), 128 + SIGKILL);
  for (pid_t service : services) {
    for (int i = 0; i < 300 && Running(service); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(50));
    EXPECT_FALSE(Running(service)) << "service " << service << " still runs 15 s after the launcher was killed";
    if (Running(service)) kill(service, SIGKILL);
  }
}

}  // namespace
}  // namespace stitch
