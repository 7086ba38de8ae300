// The quality gate's rules on constructed figures: its file read and refused, regressions found
// in the worse direction only, beyond the tolerance only, and a missing figure counted.

#include "tools/stitch/quality/quality_gate.h"

#include <cmath>
#include <fstream>

#include <gtest/gtest.h>

#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

const char kMatrix[] = R"(tolerance:
  frames_in_largest_map: {relative: 0.02, absolute: 2, better: higher}
  ate_m: {relative: 0.15, absolute: 0.005, better: lower}
  wrong_merges: {relative: 0, absolute: 0, better: lower}
cases:
  - name: tum
    run: ["--dataset", "${datasets}/tum/rgbd_dataset_freiburg1_rpy", "--failures", "300:10,500:10"]
    needs: tum/rgbd_dataset_freiburg1_rpy
    alone: true
    repeats: 3
    tolerance:
      ate_m: {relative: 0.5}
    expect: {frames_in_largest_map: 697, ate_m: 0.048, wrong_merges: 0}
  - name: short
    run: ["--max-frames", "300"]
    ci: true
)";

QualityMatrix WriteAndLoad(const testing::TempDir& dir, const std::string& text) {
  const std::string path = dir / "quality.yaml";
  std::ofstream(path) << text;
  return LoadQualityMatrix(path);
}

TEST(QualityGate, ReadsTheMatrixAndACasesOwnTolerance) {
  testing::TempDir dir;
  const QualityMatrix matrix = WriteAndLoad(dir, kMatrix);
  ASSERT_EQ(matrix.cases.size(), 2u);
  const QualityCase& tum = matrix.cases[0];
  EXPECT_EQ(tum.name, "tum");
  EXPECT_TRUE(tum.alone);
  EXPECT_FALSE(tum.ci);
  EXPECT_EQ(tum.repeats, 3);
  EXPECT_EQ(matrix.cases[1].repeats, 1) << "one run unless told";
  EXPECT_EQ(tum.expect.at("frames_in_largest_map"), 697);
  EXPECT_DOUBLE_EQ(tum.tolerance.at("ate_m").relative, 0.5);
  EXPECT_DOUBLE_EQ(tum.tolerance.at("ate_m").absolute, 0.005) << "the rest from the defaults";
  EXPECT_TRUE(matrix.cases[1].ci);
  EXPECT_EQ(ReproduceCommand(tum, "/data"),
            "build/bin/stitch run --dataset /data/tum/rgbd_dataset_freiburg1_rpy --failures 300:10,500:10");
  // Written back and read again: the same matrix.
  SaveQualityMatrix(matrix, dir / "again.yaml");
  const QualityMatrix again = LoadQualityMatrix(dir / "again.yaml");
  ASSERT_EQ(again.cases.size(), 2u);
  EXPECT_EQ(again.cases[0].run, tum.run);
  EXPECT_EQ(again.cases[0].expect, tum.expect);
  EXPECT_EQ(again.cases[0].repeats, 3);
  EXPECT_DOUBLE_EQ(again.cases[0].tolerance.at("ate_m").relative, 0.5);
}

TEST(QualityGate, RefusesAMatrixItCannotCheck) {
  testing::TempDir dir;
  const auto refused = [&](const std::string& text, const std::string& what) {
    try {
      WriteAndLoad(dir, text);
      ADD_FAILURE() << "accepted: " << what;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  };
  refused("tolerance: {}\ncases:\n  - name: a\n    expect: {ate_m: 1}\n", "no tolerance for 'ate_m'");
  refused("tolerance: {}\ncases:\n  - name: a\n    expect: {speed: 1}\n", "unknown figure 'speed'");
  refused("tolerance: {}\ncases:\n  - name: a\n    colour: red\n", "unknown key 'colour'");
  refused("tolerance: {}\ncases:\n  - name: a\n  - name: a\n", "two cases named 'a'");
  refused("tolerance: {ate_m: {relative: -1}}\ncases:\n  - name: a\n", "slack must be >= 0");
  refused("tolerance: {}\ncases:\n  - name: a\n    repeats: 0\n", "repeats must be in [1, 20]");
  refused("tolerance: {}\ncases: [\n", "quality.yaml");
  refused("tolerance: {}\ncases:\n  - name: a\n    render: [\"--max-frames\", \"9\"]\n", "give both or neither");
  refused("tolerance: {}\ncases:\n  - name: a\n    run: [\"--dataset\", \"${rendered}\"]\n", "give both or neither");
}

// A case that plays a clip it renders: the clip's path stands for ${rendered}, and the command
// that reproduces the case renders it first.
TEST(QualityGate, ACaseThatRendersItsClipPlaysItAndSaysHowToMakeIt) {
  testing::TempDir dir;
  const QualityMatrix matrix = WriteAndLoad(
      dir,
      "tolerance: {}\ncases:\n  - name: hd\n    run: [\"--dataset\", \"${rendered}\", \"--pacing\", \"realtime\"]\n"
      "    render: [\"--set\", \"synthetic.width=1920\"]\n");
  const QualityCase& hd = matrix.cases[0];
  EXPECT_EQ(hd.render, (std::vector<std::string>{"--set", "synthetic.width=1920"}));
  EXPECT_EQ(CaseRunArguments(hd, "/data", "/runs/q/clips/hd.mp4"),
            (std::vector<std::string>{"--dataset", "/runs/q/clips/hd.mp4", "--pacing", "realtime"}));
  EXPECT_EQ(ReproduceCommand(hd, "/data"),
            "build/bin/stitch render --set synthetic.width=1920 --out hd.mp4 && build/bin/stitch run --dataset hd.mp4 "
            "--pacing realtime");
  // Written back as read.
  SaveQualityMatrix(matrix, dir / "again.yaml");
  EXPECT_EQ(LoadQualityMatrix(dir / "again.yaml").cases[0].render, hd.render);
}

// A case run from several start frames (where a rotating camera's map starts decides much):
// one run from each, `--start-frame` added, checked on the median and on the worst start, each
// against its own expectation.
TEST(QualityGate, ACaseFromSeveralStartFramesRunsOnceFromEach) {
  testing::TempDir dir;
  const QualityMatrix matrix =
      WriteAndLoad(dir,
                   "tolerance: {}\ncases:\n  - name: starts\n    run: [\"--failures\", \"none\"]\n"
                   "    start_frames: [0, 8, 16]\n");
  const QualityCase& starts = matrix.cases[0];
  EXPECT_EQ(starts.repeats, 3);
  EXPECT_EQ(CaseRunArguments(starts, "/data", "", 1),
            (std::vector<std::string>{"--failures", "none", "--start-frame", "8"}));
  EXPECT_EQ(ReproduceCommand(starts, "/data"),
            "build/bin/stitch run --failures none --start-frame 0  # and with --start-frame 8, 16");
  SaveQualityMatrix(matrix, dir / "again.yaml");
  EXPECT_EQ(LoadQualityMatrix(dir / "again.yaml").cases[0].start_frames, starts.start_frames);
  // The worst start is a figure of its own (no run-to-run noise): held to expect_worst.
  const QualityMatrix expected =
      WriteAndLoad(dir,
                   "tolerance:\n  frames_in_largest_map: {relative: 0.02, absolute: 2, better: higher}\ncases:\n"
                   "  - name: starts\n    start_frames: [0, 8, 16]\n    expect: {frames_in_largest_map: 679}\n"
                   "    expect_worst: {frames_in_largest_map: 633}\n");
  const QualityCase& held = expected.cases[0];
  const std::map<std::string, double> worst_start = {{"frames_in_largest_map", 633}};
  EXPECT_TRUE(CheckCase(expected, held, worst_start, {}, /*worst_run=*/true).empty());
  EXPECT_EQ(CheckCase(expected, held, worst_start).size(), 1u) << "the median's expectation would fail it";
  const auto fell = CheckCase(expected, held, {{"frames_in_largest_map", 600}}, {}, /*worst_run=*/true);
  ASSERT_EQ(fell.size(), 1u);
  EXPECT_TRUE(fell[0].worst_run);
  EXPECT_NE(fell[0].Describe().find("worst run: frames_in_largest_map 600, expected 633"), std::string::npos)
      << fell[0].Describe();
  SaveQualityMatrix(expected, dir / "again.yaml");
  EXPECT_EQ(LoadQualityMatrix(dir / "again.yaml").cases[0].expect_worst, held.expect_worst);
  try {
    WriteAndLoad(dir,
                 "tolerance:\n  ate_m: {relative: 0, absolute: 0, better: lower}\ncases:\n  - name: a\n"
                 "    expect_worst: {ate_m: 1}\n");
    ADD_FAILURE() << "expect_worst without start_frames accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("needs start_frames"), std::string::npos) << e.what();
  }
  try {
    WriteAndLoad(dir, "tolerance: {}\ncases:\n  - name: a\n    start_frames: [0, 8]\n    repeats: 3\n");
    ADD_FAILURE() << "repeats beside start_frames accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("leave repeats out"), std::string::npos) << e.what();
  }
  try {
    WriteAndLoad(dir, "tolerance: {}\ncases:\n  - name: a\n    start_frames: [0, -8]\n");
    ADD_FAILURE() << "a negative start frame accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("frame numbers"), std::string::npos) << e.what();
  }
}

TEST(QualityGate, ARegressionIsAFigureWorseThanItsToleranceAllows) {
  testing::TempDir dir;
  const QualityMatrix matrix = WriteAndLoad(dir, kMatrix);
  const QualityCase& tum = matrix.cases[0];
  // Within tolerance (697 - 2% - 2 = 681.06; 0.048 + 50% + 0.005 = 0.077), and better: none.
  EXPECT_TRUE(CheckCase(matrix, tum, {{"frames_in_largest_map", 682}, {"ate_m", 0.076}, {"wrong_merges", 0}}).empty());
  EXPECT_TRUE(CheckCase(matrix, tum, {{"frames_in_largest_map", 723}, {"ate_m", 0.01}, {"wrong_merges", 0}}).empty());
  // Worse beyond it: each named, with its limit.
  const auto regressions =
      CheckCase(matrix, tum, {{"frames_in_largest_map", 546}, {"ate_m", 0.078}, {"wrong_merges", 1}});
  ASSERT_EQ(regressions.size(), 3u);
  EXPECT_EQ(regressions[0].figure, "ate_m");
  EXPECT_NEAR(regressions[0].limit, 0.077, 1e-12);
  EXPECT_EQ(regressions[1].figure, "frames_in_largest_map");
  EXPECT_NE(regressions[1].Describe().find("546, expected 697"), std::string::npos) << regressions[1].Describe();
  EXPECT_EQ(regressions[2].figure, "wrong_merges");
  // A figure the run no longer gives (no ATE: the map was lost) is a regression too.
  const auto missing = CheckCase(matrix, tum, {{"frames_in_largest_map", 697}, {"wrong_merges", 0}});
  ASSERT_EQ(missing.size(), 1u);
  EXPECT_TRUE(std::isnan(missing[0].measured));
  EXPECT_NE(missing[0].Describe().find("missing"), std::string::npos);
  // --figures: only those figures are compared.
  const auto only_ate = CheckCase(matrix, tum, {{"frames_in_largest_map", 546}, {"ate_m", 0.078}}, {"ate_m"});
  ASSERT_EQ(only_ate.size(), 1u);
  EXPECT_EQ(only_ate[0].figure, "ate_m");
}

TEST(QualityGate, ARepeatedCaseIsItsMedianAndItsWorstRunTheWorseWayOfEachFigure) {
  testing::TempDir dir;
  const QualityMatrix matrix = WriteAndLoad(dir, kMatrix);
  const QualityCase& tum = matrix.cases[0];
  // Three real-time runs: the second lost most of its frames, the third has no ATE.
  const RepeatedFigures combined =
      CombineRuns(matrix, tum,
                  {{{"frames_in_largest_map", 700}, {"ate_m", 0.030}, {"dropped_frames", 0}},
                   {{"frames_in_largest_map", 365}, {"ate_m", 0.050}, {"dropped_frames", 150}},
                   {{"frames_in_largest_map", 690}, {"dropped_frames", 2}}});
  EXPECT_EQ(combined.median.at("frames_in_largest_map"), 690);
  EXPECT_EQ(combined.median.at("ate_m"), 0.050)
      << "the median (the upper middle: Median) of the two runs that have one";
  EXPECT_EQ(combined.median.at("dropped_frames"), 2);
  EXPECT_EQ(combined.worst.at("frames_in_largest_map"), 365) << "higher is better: the worst is the lowest";
  EXPECT_EQ(combined.worst.at("dropped_frames"), 150) << "no tolerance: higher is worse";
  EXPECT_EQ(combined.worst.count("ate_m"), 0u) << "a run without an ATE: the worst has none (a regression)";
  // Its median passes; its worst run does not.
  EXPECT_TRUE(CheckCase(matrix, tum, combined.median, {"frames_in_largest_map"}).empty());
  EXPECT_EQ(CheckCase(matrix, tum, combined.worst, {"frames_in_largest_map"}).size(), 1u);
  // Mostly absent: no median either.
  const RepeatedFigures sparse = CombineRuns(matrix, tum, {{{"ate_m", 0.03}}, {}, {}});
  EXPECT_EQ(sparse.median.count("ate_m"), 0u);
}

TEST(QualityGate, TheMarkdownTableReplacesOnlyWhatLiesBetweenItsMarkers) {
  const std::string document =
      "# Benchmarks\n\ntext before\n<!-- quality-gate -->\nold table\nold row\n<!-- /quality-gate -->\ntext after\n";
  EXPECT_EQ(PlaceMarkdownTable(document, "new table\n"),
            "# Benchmarks\n\ntext before\n<!-- quality-gate -->\nnew table\n<!-- /quality-gate -->\ntext after\n");
  // Without both markers (or a new, empty file): the table is the whole file.
  EXPECT_EQ(PlaceMarkdownTable("", "new table\n"), "new table\n");
  EXPECT_EQ(PlaceMarkdownTable("<!-- quality-gate -->\nno end\n", "t\n"), "t\n");
}

}  // namespace
}  // namespace stitch
