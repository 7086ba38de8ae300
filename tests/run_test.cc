// `stitch run` end to end: the real service processes over UDP multicast.

#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "stitch/io/ply.h"
#include "stitch/io/trajectory.h"
#include "stitch/records/frame_record.h"
#include "stitch/testing/temp_dir.h"
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

}  // namespace
}  // namespace stitch
