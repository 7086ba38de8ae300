// stitch bench --realtime: a case's margin in real time (margin.h).

#include "tools/stitch/quality/margin.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <thread>

#include <nlohmann/json.hpp>

#include "stitch/source/source.h"
#include "stitch/util/args.h"
#include "stitch/util/child_process.h"
#include "stitch/util/error.h"
#include "stitch/util/text_file.h"
#include "stitch/util/time.h"
#include "tools/stitch/quality/quality_gate.h"

namespace fs = std::filesystem;

namespace stitch {

Margin FindMargin(const std::function<MarginTrial(double speed)>& play, const MarginOptions& options) {
  if (!(options.lowest_speed > 0 && options.lowest_speed <= 1 && options.highest_speed >= 1 &&
        options.highest_speed <= 100)) {
    throw Error("the speeds tried must bracket 1, within (0, 100]");
  }
  if (!(options.resolution > 0.001)) throw Error("the resolution must be above 0.001");
  Margin margin;
  const auto try_speed = [&](double speed) {
    MarginTrial trial = play(speed);
    trial.speed = speed;
    trial.kept_up = trial.dropped_share <= options.max_dropped_share;
    margin.trials.push_back(trial);
    return trial.kept_up;
  };
  double kept = 0, lost = 0;  // the bracket: the fastest speed that kept up, the slowest that did not
  if (try_speed(1)) {
    kept = 1;
    for (double speed = 2; !lost; speed *= 2) {
      speed = std::min(speed, options.highest_speed);
      if (speed <= kept) break;
      (try_speed(speed) ? kept : lost) = speed;
    }
    if (!lost) {
      margin.speed = kept;
      margin.capped = true;
      return margin;
    }
  } else {
    lost = 1;
    for (double speed = 0.5; !kept; speed /= 2) {
      speed = std::max(speed, options.lowest_speed);
      if (speed >= lost) break;
      (try_speed(speed) ? kept : lost) = speed;
    }
    if (!kept) return margin;  // not even at the lowest speed
  }
  while (lost / kept > 1 + options.resolution) {
    // Two decimals, as a reader would set ingest.speed.
    const double middle = std::round(std::sqrt(kept * lost) * 100) / 100;
    if (middle <= kept || middle >= lost) break;
    (try_speed(middle) ? kept : lost) = middle;
  }
  margin.speed = kept;
  return margin;
}

namespace {

constexpr const char* kQualityMatrix = STITCH_SOURCE_DIR "/benchmarks/quality.yaml";

std::string SpeedText(double speed) {
  char text[16];
  std::snprintf(text, sizeof(text), "%.2f", speed);
  return text;
}

void PrintTrials(const Margin& margin, bool markdown, std::FILE* out) {
  const char* header[] = {
      "speed",   "dropped",     "sent late", "of frames", "frames in largest map", "submaps (merged)",
      "ATE [m]", "CPU s/frame", "wall [s]",  "kept up"};
  std::string line = markdown ? "|" : "";
  for (const char* h : header) line += std::string(markdown ? " " : "") + h + (markdown ? " |" : "  ");
  std::fprintf(out, "%s\n", line.c_str());
  if (markdown) {
    std::string rule = "|";
    for (size_t i = 0; i < std::size(header); ++i) rule += "---|";
    std::fprintf(out, "%s\n", rule.c_str());
  }
  std::vector<MarginTrial> trials = margin.trials;
  std::sort(trials.begin(), trials.end(), [](const MarginTrial& a, const MarginTrial& b) { return a.speed < b.speed; });
  for (const MarginTrial& t : trials) {
    const auto figure = [&](const char* key, const char* format) {
      const auto it = t.figures.find(key);
      if (it == t.figures.end()) return std::string("n/a");
      char text[32];
      std::snprintf(text, sizeof(text), format, it->second);
      return std::string(text);
    };
    char share[16];
    std::snprintf(share, sizeof(share), "%.1f%%", 100 * t.dropped_share);
    const std::string cells[] = {SpeedText(t.speed),
                                 figure("dropped_frames", "%.0f"),
                                 figure("source_late_frames", "%.0f"),
                                 share,
                                 figure("frames_in_largest_map", "%.0f"),
                                 figure("submaps", "%.0f") + " (" + figure("submaps_merged", "%.0f") + ")",
                                 figure("ate_m", "%.4f"),
                                 figure("cpu_s_per_frame", "%.4f"),
                                 figure("wall_s", "%.0f"),
                                 t.kept_up ? "yes" : "no"};
    line = markdown ? "|" : "";
    for (const std::string& c : cells) line += (markdown ? " " : "") + c + (markdown ? " |" : "  ");
    std::fprintf(out, "%s\n", line.c_str());
  }
}

std::string MarginSentence(const Margin& margin, double max_dropped_share) {
  char text[200];
  if (margin.speed == 0) {
    std::snprintf(text, sizeof(text),
                  "margin: none (more than %.1f%% of frames dropped or sent late even at the slowest speed)",
                  100 * max_dropped_share);
  } else {
    std::snprintf(text, sizeof(text),
                  "margin: %s%.2fx (the fastest playback dropping or sending late at most %.1f%% of frames)",
                  margin.capped ? "at least " : "", margin.speed, 100 * max_dropped_share);
  }
  return text;
}

}  // namespace

int MarginCommand(int argc, char** argv) {
  std::string case_name, expected_path = kQualityMatrix, datasets_dir, config_path, out_dir, json_path, markdown_path,
                         label;
  std::vector<std::string> settings;
  SourceSpec source;  // without --case
  bool realtime = false;
  MarginOptions options;
  ArgParser args("stitch bench --realtime",
                 "The margin in real time: plays a case with `stitch run --pacing realtime` (as separate processes, "
                 "like the gate) at playback speed 1, then faster (or slower) until it drops more (or at most) than "
                 "--max-dropped of its frames, then bisects: the highest speed (ingest.speed) that still keeps up. A "
                 "frame the source itself sent more than a frame late (decoding and reducing a video cost CPU too) "
                 "counts as dropped: the run played slower than the speed asked. A machine half as fast as this one "
                 "sees the camera at speed 2. Run it with nothing beside it.");
  args.AddFlag("--realtime", &realtime, "(this mode of stitch bench)");
  args.AddOption("--case", &case_name, "NAME", "a case of the quality gate (its run arguments; e.g. tum-realtime)");
  args.AddOption("--expected", &expected_path, "FILE", "the gate's matrix, for --case");
  args.AddOption("--datasets", &datasets_dir, "DIR",
                 "the real sequences' folder, for --case (default: $STITCH_DATASETS or ../shared/datasets)");
  AddSourceOptions(&args, &source, kDatasetFlag | kCalibFlag | kFailuresFlag | kMaxFramesFlag | kStartFrameFlag);
  args.AddOption("--config", &config_path, "FILE", "YAML settings for the runs");
  args.AddOption("--set", &settings, "KEY=VALUE", "a setting for every run");
  args.AddOption("--max-dropped", &options.max_dropped_share, "SHARE",
                 "the share of frames a run may drop (or its source send late) and still keep up (default 0.01)");
  args.AddOption("--lowest", &options.lowest_speed, "SPEED", "the slowest speed tried (default 0.25)");
  args.AddOption("--highest", &options.highest_speed, "SPEED", "the fastest speed tried (default 8)");
  args.AddOption("--resolution", &options.resolution, "RATIO",
                 "stop when the fastest speed that kept up and the slowest that did not are within 1 + RATIO "
                 "(default 0.1)");
  args.AddOption("--out", &out_dir, "DIR", "where the runs go (default: runs/margin-<time>)");
  args.AddOption("--json", &json_path, "FILE", "also write the trials and the margin as JSON");
  args.AddOption("--markdown", &markdown_path, "FILE",
                 "write the trials' table into FILE between <!-- realtime-margin LABEL --> and "
                 "<!-- /realtime-margin LABEL --> (the whole file when it lacks them)");
  args.AddOption("--label", &label, "LABEL", "the table's name in --markdown (default: the case, or 'run')");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    std::vector<std::string> run_args = SourceArguments(source);
    const QualityCase* clip_case = nullptr;  // a case whose clip is rendered first
    QualityMatrix matrix;
    if (!case_name.empty()) {
      if (!run_args.empty()) throw Error("--case plays the case's own sequence: leave out the source's flags");
      matrix = LoadQualityMatrix(expected_path);
      const auto c = std::find_if(matrix.cases.begin(), matrix.cases.end(),
                                  [&](const QualityCase& q) { return q.name == case_name; });
      if (c == matrix.cases.end()) throw Error("--case: no case named '" + case_name + "' in " + expected_path);
      if (datasets_dir.empty()) datasets_dir = DefaultDatasetsDir();
      if (!c->needs.empty() && !fs::exists(fs::path(datasets_dir) / c->needs))
        throw Error("case '" + case_name + "' needs " + c->needs + ", which is not in " + datasets_dir);
      clip_case = &*c;
      run_args = CaseRunArguments(*c, datasets_dir);
    } else {
      CheckSourceSpec(source);
    }
    if (!(options.max_dropped_share >= 0 && options.max_dropped_share < 1))
      throw Error("--max-dropped must be in [0, 1)");
    if (label.empty()) label = case_name.empty() ? "run" : case_name;
    if (out_dir.empty()) out_dir = "runs/margin-" + LocalTimestamp("%Y%m%d-%H%M%S");
    if (fs::exists(out_dir) && !fs::is_empty(out_dir))
      throw Error(out_dir + " exists and is not empty; give a new --out");
    fs::create_directories(out_dir);
    if (clip_case != nullptr && !clip_case->render.empty()) {
      run_args =
          CaseRunArguments(*clip_case, datasets_dir, RenderCaseClip(*clip_case, (fs::path(out_dir) / "clip").string()));
    }
    if (!config_path.empty()) {
      run_args.push_back("--config");
      run_args.push_back(config_path);
    }
    for (const std::string& setting : settings) {
      run_args.push_back("--set");
      run_args.push_back(setting);
    }
    const std::string stitch = ExecutableDir() + "/stitch";
    const auto play = [&](double speed) {
      const std::string run_dir = (fs::path(out_dir) / ("speed-" + SpeedText(speed))).string();
      std::vector<std::string> a{"run", "--quiet", "--out", run_dir};
      a.insert(a.end(), run_args.begin(), run_args.end());
      a.insert(a.end(), {"--pacing", "realtime", "--set", "ingest.speed=" + SpeedText(speed)});
      std::printf("speed %s ...", SpeedText(speed).c_str());
      std::fflush(stdout);
      const Stopwatch clock;
      ChildProcess child("run", stitch, a, run_dir + ".log");
      std::optional<int> status;
      while (!(status = child.Poll())) std::this_thread::sleep_for(std::chrono::milliseconds(200));
      if (*status != 0) {
        throw Error("stitch run at speed " + SpeedText(speed) + " exited with status " + std::to_string(*status) +
                    ":\n" + child.LogTail(8));
      }
      MarginTrial trial;
      trial.figures = MeasureRun(run_dir, child.cpu_seconds(), clock.ElapsedSeconds());
      const double total = trial.figures.at("frames_total");
      // A frame the source sent late is one a camera would not have waited for: the run played
      // slower than the speed asked, so it counts as a frame not kept up with.
      const double late = trial.figures.at("source_late_frames");
      // (A frame may be both; the share counts it twice, up to all of them.)
      trial.dropped_share = total > 0 ? std::min(1.0, (trial.figures.at("dropped_frames") + late) / total) : 1;
      std::printf(
          " %.0f of %.0f frames dropped%s (%.1f%%), %.0f in the largest map, %.0f s\n",
          trial.figures.at("dropped_frames"), total,
          late > 0 ? (" and " + std::to_string(static_cast<int>(late)) + " sent late by the source").c_str() : "",
          100 * trial.dropped_share, trial.figures.at("frames_in_largest_map"), clock.ElapsedSeconds());
      std::fflush(stdout);
      return trial;
    };
    const Margin margin = FindMargin(play, options);
    std::printf("\n");
    PrintTrials(margin, /*markdown=*/false, stdout);
    const std::string sentence = MarginSentence(margin, options.max_dropped_share);
    std::printf("\n%s\n", sentence.c_str());
    if (!json_path.empty()) {
      nlohmann::json json{{"label", label},
                          {"margin", margin.speed},
                          {"capped", margin.capped},
                          {"max_dropped_share", options.max_dropped_share},
                          {"run", run_args}};
      for (const MarginTrial& t : margin.trials) {
        json["trials"].push_back(
            {{"speed", t.speed}, {"dropped_share", t.dropped_share}, {"kept_up", t.kept_up}, {"figures", t.figures}});
      }
      WriteFileAtomically(json_path, json.dump(2) + "\n");
    }
    if (!markdown_path.empty()) {
      const std::string begin = "<!-- realtime-margin " + label + " -->";
      const std::string end = "<!-- /realtime-margin " + label + " -->";
      std::string command = "build/bin/stitch bench --realtime";
      if (!case_name.empty()) command += " --case " + case_name;
      for (const std::string& a : case_name.empty() ? run_args : std::vector<std::string>()) command += " " + a;
      WriteMarkdownTable(
          markdown_path, command,
          [&](std::FILE* md) {
            PrintTrials(margin, /*markdown=*/true, md);
            std::fprintf(md, "\n%s\n", sentence.c_str());
          },
          begin.c_str(), end.c_str());
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch bench --realtime: %s\n", e.what());
    return 2;
  }
}

}  // namespace stitch
