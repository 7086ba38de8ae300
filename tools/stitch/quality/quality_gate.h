#pragma once
// The quality gate (`stitch bench --quality`): a fixed matrix of `stitch run` cases, each
// measured the same way (accuracy, merges, keyframes, tracked points, CPU of all services, wall
// time, frames dropped), compared against committed expectations with tolerances
// (benchmarks/quality.yaml). docs/testing.md, "The quality gate".

#include <cstdio>
#include <functional>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace stitch {

// How much a figure may move before it is a regression, and which way is worse.
struct Tolerance {
  double relative = 0;  // of the expected value
  double absolute = 0;
  bool higher_is_better = false;
};

struct QualityCase {
  std::string name;
  std::string about;
  std::vector<std::string> run;  // `stitch run` arguments; ${datasets} is the datasets folder
  // `stitch render` arguments that make the clip the case plays (a camera whose frames cannot be
  // rendered at its rate while it runs: 1080p, 4K), rendered before its runs; ${rendered} in
  // `run` is that clip.
  std::vector<std::string> render;
  std::string needs;   // a folder under the datasets folder the case plays ("" = none)
  bool alone = false;  // runs with nothing beside it (CPU, real time, link timing)
  bool ci = false;     // part of the subset ctest runs
  int repeats = 1;     // runs (real time varies run to run): checked on median and worst
  // Each run from one of these frames (`--start-frame`; repeats is their number): how much where
  // the map starts decides, checked on the median and the worst start.
  std::vector<int> start_frames;
  std::map<std::string, double> expect;  // figure -> expected value
  // With start_frames: the worst start's expected figures (a start is not a run that varies: the
  // worst is its own figure); without, a repeated case's worst run is held to `expect`.
  std::map<std::string, double> expect_worst;
  std::map<std::string, Tolerance> tolerance;  // this case's own slack (over the defaults)
};

struct QualityMatrix {
  std::map<std::string, Tolerance> tolerance;  // the defaults, per figure
  std::vector<QualityCase> cases;
};

// Reads and checks benchmarks/quality.yaml; throws stitch::Error naming the file and what is wrong.
QualityMatrix LoadQualityMatrix(const std::string& path);
// Writes it back (the case definitions and `expect` as given in `matrix`).
void SaveQualityMatrix(const QualityMatrix& matrix, const std::string& path);

// One case's figures, from its run folder (report.json, frames.tsv, keyframes.tsv) and the
// run's CPU and wall time. Keys: frames_in_largest_map, completeness, submaps, submaps_merged,
// ate_m, worst_submap_ate_in_map_m, wrong_merges, on_earth_m (where the run was placed on Earth
// and its truth is in the fixes' frame: the largest map's keyframes' horizontal RMS error, no
// alignment), keyframes_created, keyframes_kept, median_tracked_points, cpu_s_per_frame, wall_s,
// dropped_frames; and frames_total.
std::map<std::string, double> MeasureRun(const std::string& run_dir, double cpu_seconds, double wall_seconds);

// A regression: the figure, what was measured, what was expected, and the limit it crossed.
struct Regression {
  std::string figure;
  double measured = 0, expected = 0, limit = 0;
  bool worst_run = false;  // the worst of a repeated case's runs (else its median, or its one run)
  std::string Describe() const;
};
// Every expected figure of `c` outside its tolerance (missing figures count: a case that used to
// have an ATE and now has none has regressed); only the figures in `only` when it is not empty.
// `worst_run`: `measured` is a repeated case's worst run, held to `expect_worst` where the case
// has one.
std::vector<Regression> CheckCase(const QualityMatrix& matrix, const QualityCase& c,
                                  const std::map<std::string, double>& measured, const std::set<std::string>& only = {},
                                  bool worst_run = false);

// A case run several times: per figure, the median over the runs that have it (absent when most
// lack it) and the worst run's value, the worse way of its tolerance (absent when any run lacks it;
// a figure without a tolerance is worse higher).
struct RepeatedFigures {
  std::map<std::string, double> median, worst;
};
RepeatedFigures CombineRuns(const QualityMatrix& matrix, const QualityCase& c,
                            const std::vector<std::map<std::string, double>>& runs);

// The folder ${datasets} stands for: $STITCH_DATASETS, else ../shared/datasets beside the source.
std::string DefaultDatasetsDir();
// A case's `stitch run` arguments with ${datasets} and ${rendered} (its rendered clip) replaced;
// for a case with start_frames, run `repeat`'s `--start-frame`.
std::vector<std::string> CaseRunArguments(const QualityCase& c, const std::string& datasets_dir,
                                          const std::string& rendered = "", int repeat = 0);
// Renders the clip a case with `render` plays into `dir` (stitch render as a child process, its
// log beside the clip) and returns its path. Throws stitch::Error, with the log's end, when
// rendering fails.
std::string RenderCaseClip(const QualityCase& c, const std::string& dir);

// The `stitch run` command line that reproduces a case (with `settings` added to it); for a case
// with start_frames, its first start (the others are named after it).
std::string ReproduceCommand(const QualityCase& c, const std::string& datasets_dir,
                             const std::vector<std::string>& settings = {});

// `document` with the lines between its markers replaced by `table`; `table` alone when the
// document lacks them (a new file).
constexpr const char* kMarkdownBegin = "<!-- quality-gate -->";
constexpr const char* kMarkdownEnd = "<!-- /quality-gate -->";
std::string PlaceMarkdownTable(const std::string& document, const std::string& table,
                               const char* begin = kMarkdownBegin, const char* end = kMarkdownEnd);
// Writes "`command`, DATE:" and what `print` prints into `path` between `begin` and `end`
// (PlaceMarkdownTable), as one act.
void WriteMarkdownTable(const std::string& path, const std::string& command,
                        const std::function<void(std::FILE*)>& print, const char* begin = kMarkdownBegin,
                        const char* end = kMarkdownEnd);
// The help text of a --markdown option writing between `begin` and `end`.
std::string MarkdownOptionHelp(const char* begin, const char* end);
// The merge campaign's markers (stitch campaign --markdown).
constexpr const char* kCampaignBegin = "<!-- merge-campaign -->";
constexpr const char* kCampaignEnd = "<!-- /merge-campaign -->";
// A whole file's text; throws stitch::Error when it cannot be read ("" when it does not exist).
std::string ReadWholeFile(const std::string& path);

// One case's outcome.
struct CaseResult {
  const QualityCase* c = nullptr;
  bool skipped = false;                             // its sequence is absent
  bool failed = false;                              // stitch run failed, or its outputs could not be read
  std::string why;                                  // skipped or failed: why
  std::string rendered;                             // the clip it plays, when it renders one
  std::map<std::string, double> figures;            // of its one run; the median of a repeated case's
  std::map<std::string, double> worst;              // a repeated case's worst run (CombineRuns)
  std::vector<std::map<std::string, double>> runs;  // each run's
  std::vector<Regression> regressions;
};

struct RunCasesOptions {
  std::string out_dir;                // each case's run folder goes under it (new or empty)
  std::string datasets_dir;           // ${datasets}
  int jobs = 1;                       // cases side by side (those marked alone run alone)
  std::vector<std::string> settings;  // --set for every case
  std::set<std::string> figures;      // checked against the expectations (empty: all)
};

// Runs each chosen case (`stitch run` as a child process, as many times as it repeats, progress
// on stdout) and measures and checks it. Throws stitch::Error when the folder cannot be made.
std::vector<CaseResult> RunCases(const QualityMatrix& matrix, const std::vector<const QualityCase*>& chosen,
                                 const RunCasesOptions& options);

int QualityCommand(int argc, char** argv);  // stitch bench --quality

}  // namespace stitch
