// The quality gate end to end (stitch bench --quality): its CI subset meets the committed
// expectations; a merge lost on purpose fails the check and says which figure and how to
// reproduce it; and a lockstep run is the same run on a busy machine, which the gate's
// expectations rest on.

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <vector>

#include <gtest/gtest.h>

#include "stitch/eval/evaluation.h"
#include "stitch/records/frame_record.h"
#include "stitch/records/keyframe_record.h"
#include "stitch/testing/temp_dir.h"
#include "tests/test_process.h"

namespace stitch {
namespace {

using testing::Bin;
using testing::RunProgram;

// What a lockstep run gives does not depend on the machine's speed (Determinism below), so the
// CI subset checks it everywhere; cost figures (CPU, drops) only mean something on the machine
// the expectations were measured on, and under the sanitizers not at all.
const char* kMachineIndependentFigures =
    "frames_in_largest_map,completeness,submaps,submaps_merged,ate_m,worst_submap_ate_in_map_m,wrong_merges,"
    "keyframes_created,keyframes_kept,median_tracked_points";

TEST(QualityGate, TheCiSubsetMeetsItsExpectations) {
  testing::TempDir dir;
  const auto result = RunProgram({Bin("stitch"), "bench", "--quality", "--ci", "--check", "--figures",
                                  kMachineIndependentFigures, "--out", dir / "gate"},
                                 600);
  EXPECT_EQ(result.exit_code, 0) << result.output;
  EXPECT_NE(result.output.find("0 regressed, 0 failed"), std::string::npos) << result.output;
  ASSERT_TRUE(std::filesystem::exists(dir / "gate/quality.json"));
  // The same figures tabled again without running anything, against themselves: nothing moved.
  const auto again = RunProgram(
      {Bin("stitch"), "bench", "--quality", "--ci", "--check", "--figures", kMachineIndependentFigures, "--from",
       dir / "gate/quality.json", "--before", dir / "gate/quality.json", "--markdown", dir / "table.md"},
      60);
  EXPECT_EQ(again.exit_code, 0) << again.output;
  EXPECT_EQ(again.output.find("->"), std::string::npos) << again.output;
  EXPECT_TRUE(std::filesystem::exists(dir / "table.md"));
  // Those figures as the new expectations of a copy of the matrix: with --figures, only those
  // move (the cost figures stay the machine's that measured them).
  const std::string matrix = dir / "quality.yaml";
  std::filesystem::copy_file(testing::SourceFile("benchmarks/quality.yaml"), matrix);
  const auto update = RunProgram({Bin("stitch"), "bench", "--quality", "--ci", "--expected", matrix, "--from",
                                  dir / "gate/quality.json", "--update", "--figures", "ate_m"},
                                 60);
  EXPECT_EQ(update.exit_code, 0) << update.output;
  const std::string before = testing::ReadWholeFile(testing::SourceFile("benchmarks/quality.yaml"));
  const std::string after = testing::ReadWholeFile(matrix);
  const double ate = testing::ReadJson(dir / "gate/quality.json")[0]["figures"]["ate_m"].get<double>();
  char expected_ate[32];
  std::snprintf(expected_ate, sizeof(expected_ate), "ate_m: %.4f", ate);
  EXPECT_NE(after.find(expected_ate), std::string::npos) << after;
  const auto cpu = [](const std::string& text) {
    const size_t at = text.find("cpu_s_per_frame", text.find("name: frames-300"));
    return text.substr(at, text.find_first_of(",}", at) - at);
  };
  EXPECT_EQ(cpu(after), cpu(before));
  // A file that is not a gate's output is refused, and said to be.
  const auto refused = RunProgram({Bin("stitch"), "bench", "--quality", "--from", dir / "table.md"}, 60);
  EXPECT_EQ(refused.exit_code, 2) << refused.output;
  EXPECT_NE(refused.output.find("not a quality.json"), std::string::npos) << refused.output;
}

TEST(QualityGate, ALostMergeFailsTheCheckAndSaysWhy) {
  testing::TempDir dir;
  // No connection is strong enough, and GNSS does not join them: the submaps of the first 300
  // frames stay apart.
  const auto result = RunProgram(
      {Bin("stitch"), "bench", "--quality", "--cases", "frames-300", "--check", "--figures", kMachineIndependentFigures,
       "--set", "merger.min_connection_strength=100000", "--set", "merger.join_by_gnss=false", "--out", dir / "gate"},
      600);
  EXPECT_EQ(result.exit_code, 1) << result.output;
  EXPECT_NE(result.output.find("REGRESSION frames-300"), std::string::npos) << result.output;
  EXPECT_NE(result.output.find("submaps_merged 1, expected"), std::string::npos) << result.output;
  EXPECT_NE(result.output.find("reproduce: build/bin/stitch run --max-frames 300 --set "
                               "merger.min_connection_strength=100000 --set merger.join_by_gnss=false"),
            std::string::npos)
      << result.output;
}

// frames.tsv without its timing column, keyframes.tsv and the report's figures.
struct RunSummary {
  std::vector<std::string> frames;
  std::vector<std::string> keyframes;
  Evaluation evaluation;
};

RunSummary Summarize(const std::string& dir) {
  RunSummary s;
  for (FrameRecord r : ReadFrameRecords(dir + "/frames.tsv")) {
    r.tracking_ms = 0;
    s.frames.push_back(FormatFrameRecord(r));
  }
  for (const KeyframeRecord& k : ReadKeyframeRecords(dir + "/keyframes.tsv"))
    s.keyframes.push_back(FormatKeyframeRecord(k));
  std::sort(s.keyframes.begin(), s.keyframes.end());
  s.evaluation = ReadReport(dir + "/report.json");
  return s;
}

TEST(Determinism, ALockstepRunIsTheSameRunBesideTwoBusyLoops) {
  testing::TempDir dir;
  const auto run = [&](const std::string& out) {
    const auto result = RunProgram({Bin("stitch"), "run", "--config", testing::ShortFlightConfig(), "--failures",
                                    "30:6", "--quiet", "--out", dir / out},
                                   300);
    EXPECT_EQ(result.exit_code, 0) << result.output;
  };
  run("quiet");
  {
    const testing::BusyLoops loaded(2);
    run("loaded");
  }
  const RunSummary quiet = Summarize(dir / "quiet"), loaded = Summarize(dir / "loaded");
  ASSERT_GT(quiet.frames.size(), 50u);
  EXPECT_EQ(quiet.frames, loaded.frames) << "every frame's state, pose, points and keyframe";
  EXPECT_EQ(quiet.keyframes, loaded.keyframes) << "the mapper's final keyframe poses";
  EXPECT_EQ(quiet.evaluation.frames_localized, loaded.evaluation.frames_localized);
  EXPECT_EQ(quiet.evaluation.submaps_merged, loaded.evaluation.submaps_merged);
  ASSERT_TRUE(quiet.evaluation.errors && loaded.evaluation.errors);
  EXPECT_EQ(quiet.evaluation.errors->ate_rmse_m, loaded.evaluation.errors->ate_rmse_m);
}

}  // namespace
}  // namespace stitch
