// stitch bench: times the SLAM core on a sequence, without the bus: per-frame time of each
// tracking step (median and 95th percentile over tracked frames), frames per second, mapping
// time per keyframe, peak memory, tracking losses and the accuracy of the run. With --options,
// the same sequence once per speed option switched (each in a process of its own, so each
// peak memory is its own), side by side. Pin it to one core with `taskset -c 0 build/bin/stitch
// bench` to measure what one core of a small onboard computer gets.

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <thread>

#include <nlohmann/json.hpp>

#include "stitch/config/stitch_config.h"
#include "stitch/pipeline/inline_pipeline.h"
#include "stitch/source/source.h"
#include "stitch/util/args.h"
#include "stitch/util/child_process.h"
#include "stitch/util/error.h"
#include "stitch/util/text_file.h"
#include "stitch/util/time.h"
#include "tools/stitch/commands.h"
#include "tools/stitch/quality/margin.h"
#include "tools/stitch/quality/quality_gate.h"

namespace stitch {
namespace {

struct Stat {
  double median = 0, p95 = 0, mean = 0;
  int count = 0;
};

Stat Summarize(std::vector<double> values) {
  Stat s;
  if (values.empty()) return s;
  std::sort(values.begin(), values.end());
  s.count = static_cast<int>(values.size());
  s.median = values[values.size() / 2];
  s.p95 = values[std::min(values.size() - 1, static_cast<size_t>(0.95 * values.size()))];
  double sum = 0;
  for (double v : values) sum += v;
  s.mean = sum / values.size();
  return s;
}

struct BenchArgs {
  SourceSpec source;  // with failures "none" by default: the flight without gusts
  std::string config_path, json_path;
  std::vector<std::string> settings;  // --set, each KEY=VALUE, as every stitch command takes them
};

std::string JoinSettings(const std::vector<std::string>& settings) {
  std::string joined;
  for (const std::string& s : settings) joined += (joined.empty() ? "" : ", ") + s;
  return joined;
}

// One run in this process: prints the figures and returns them as JSON.
nlohmann::json BenchOnce(const BenchArgs& a) {
  StitchConfig config = ApplySettings(LoadStitchConfig(a.config_path), a.settings);
  ApplyProcessSettings(config);
  const Vocabulary vocabulary = LoadVocabulary(config);
  SourceSpec spec = a.source;
  spec.synthetic = config.synthetic;
  spec.max_working_pixels = config.ingest.max_working_pixels;  // as the run's ingest sends them
  spec.video_deblocking = config.ingest.video_deblocking;
  FailureSchedule spoil;
  auto sequence = OpenSource(spec, &spoil);
  if (!spoil.empty()) throw Error("stitch bench applies failure schedules to the synthetic flight only");
  if (config.tracker.tracking.rolling_shutter_line_us < 0) {
    config.tracker.tracking.rolling_shutter_line_us = SourceLineDelayUs(spec, sequence->camera());
  }
  std::printf("stitch bench: %s, %dx%d%s%s\n", sequence->description().c_str(), sequence->camera().width(),
              sequence->camera().height(), a.settings.empty() ? "" : ", ", JoinSettings(a.settings).c_str());
  const Stopwatch clock;
  int done = 0;
  const InlineRun run = RunInline(*sequence, config.pipeline(), vocabulary, [&](const InlineFrame&) {
    if (++done % 100 == 0) {
      std::printf("\r  %d frames", done);
      std::fflush(stdout);
    }
  });
  std::printf("\r  %d frames in %.1f s\n", done, clock.ElapsedSeconds());
  std::vector<double> extraction, frame_to_frame, local_map, keyframe, total, all_frames, mapping, merger;
  std::vector<double> insert, cull_points, triangulate, fuse, bundle_adjustment, cull_keyframes;
  std::vector<double> window_free, window_fixed, window_points, window_observations;  // local bundle adjustments
  std::map<std::string, int> tracked_by;
  int losses = 0;  // changes into the LOST state
  TrackingState previous = TrackingState::kNotTracked;
  for (const InlineFrame& f : run.frames) {
    all_frames.push_back(f.result.timings.total);
    if (f.mapping_ms > 0) {
      mapping.push_back(f.mapping_ms);
      merger.push_back(f.merger_ms);
    }
    for (const MappingReport& report : f.mapped) {
      if (report.duplicate) continue;
      const MappingStageTimes& stage = report.stage_ms;
      insert.push_back(stage.insert);
      cull_points.push_back(stage.cull_points);
      triangulate.push_back(stage.triangulate);
      fuse.push_back(stage.fuse);
      bundle_adjustment.push_back(stage.bundle_adjustment);
      cull_keyframes.push_back(stage.cull_keyframes);
      const BundleAdjustmentReport& window = report.bundle_adjustment;
      if (window.points == 0) continue;
      window_free.push_back(window.keyframes_free);
      window_fixed.push_back(window.keyframes_fixed);
      window_points.push_back(window.points);
      window_observations.push_back(window.observations);
    }
    losses += f.result.state == TrackingState::kLost && previous != TrackingState::kLost;
    previous = f.result.state;
    // Tracked frames (a frame followed by optical flow has no local-map step; others without one
    // were placed otherwise: initialization, relocalization).
    const bool followed = std::string(f.result.tracked_by) == "optical flow";
    if (f.result.state != TrackingState::kOk || (f.result.timings.local_map == 0 && !followed)) continue;
    ++tracked_by[*f.result.tracked_by ? f.result.tracked_by : "relocalization"];
    extraction.push_back(f.result.timings.extraction);
    frame_to_frame.push_back(f.result.timings.frame_to_frame);
    local_map.push_back(f.result.timings.local_map);
    keyframe.push_back(f.result.timings.keyframe);
    total.push_back(f.result.timings.total);
  }
  EvaluationInput input;
  input.frames_total = static_cast<int>(run.frames.size());
  input.poses = run.poses;
  input.ground_truth = sequence->ground_truth();
  input.keyframes = run.keyframes;
  input.submaps = run.submaps;
  const Evaluation evaluation = Evaluate(input);
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  const double peak_mb = usage.ru_maxrss / 1024.0;
  nlohmann::json json;
  json["sequence"] = sequence->description();
  json["width"] = sequence->camera().width();
  json["height"] = sequence->camera().height();
  json["settings"] = JoinSettings(a.settings);
  std::printf("\n  per tracked frame (%zu frames)   median     p95    mean   [ms]\n", total.size());
  const std::pair<const char*, const std::vector<double>*> rows[] = {{"feature extraction", &extraction},
                                                                     {"frame-to-frame tracking", &frame_to_frame},
                                                                     {"local-map tracking", &local_map},
                                                                     {"keyframe decision", &keyframe},
                                                                     {"whole frame", &total},
                                                                     {"every frame (any state)", &all_frames},
                                                                     {"mapping, per keyframe", &mapping},
                                                                     {"  insertion", &insert},
                                                                     {"  point culling", &cull_points},
                                                                     {"  triangulation", &triangulate},
                                                                     {"  fusion", &fuse},
                                                                     {"  local bundle adjustment", &bundle_adjustment},
                                                                     {"  keyframe culling", &cull_keyframes},
                                                                     {"merger, per keyframe", &merger}};
  for (const auto& [name, values] : rows) {
    const Stat s = Summarize(*values);
    std::printf("  %-32s %7.2f %7.2f %7.2f\n", name, s.median, s.p95, s.mean);
    json["ms"][name] = {{"median", s.median}, {"p95", s.p95}, {"mean", s.mean}, {"count", s.count}};
  }
  std::printf("  local bundle adjustment window   median     p95    mean\n");
  const std::pair<const char*, const std::vector<double>*> window_rows[] = {{"keyframes free", &window_free},
                                                                            {"keyframes fixed", &window_fixed},
                                                                            {"points", &window_points},
                                                                            {"observations", &window_observations}};
  for (const auto& [name, values] : window_rows) {
    const Stat s = Summarize(*values);
    std::printf("  %-32s %7.0f %7.0f %7.0f\n", name, s.median, s.p95, s.mean);
    json["local_bundle_adjustment"][name] = {{"median", s.median}, {"p95", s.p95}, {"mean", s.mean}};
  }
  const Stat frame_stat = Summarize(all_frames);
  const double fps = frame_stat.mean > 0 ? 1000.0 / frame_stat.mean : 0;
  std::printf("  tracking throughput %.1f frames/s (tracker alone), peak memory %.0f MB\n", fps, peak_mb);
  std::string placed;
  for (const auto& [method, count] : tracked_by)
    placed += (placed.empty() ? "" : ", ") + method + " " + std::to_string(count);
  std::printf("  tracked frames placed by: %s; tracking lost %d time(s)\n", placed.c_str(), losses);
  std::printf("%s", stitch::Summarize(evaluation).c_str());
  json["tracking_fps"] = fps;
  json["peak_memory_mb"] = peak_mb;
  json["losses"] = losses;
  json["tracked_by"] = tracked_by;
  json["evaluation"] = ToJson(evaluation);
  return json;
}

struct Variant {
  std::string name, settings;
};

// The configuration as given, then each speed option switched the other way.
std::vector<Variant> SpeedVariants(const StitchConfig& config) {
  const TrackingOptions& t = config.tracker.tracking;
  std::vector<Variant> variants{{"as configured", ""}};
  variants.push_back(
      {std::string("homography tracking ") + (t.homography_tracking ? "off" : "on"),
       std::string("tracker.tracking.homography_tracking=") + (t.homography_tracking ? "false" : "true")});
  const int roi = t.homography_roi_per_cell > 0 ? 0 : 6;
  variants.push_back({std::string("homography region of interest ") + (roi > 0 ? "on" : "off"),
                      "tracker.tracking.homography_roi_per_cell=" + std::to_string(roi)});
  for (const char* matching : {"bow", "lsh", "brute_force"}) {
    if (t.reference_matching == matching) continue;
    variants.push_back({std::string("reference matching ") + matching,
                        std::string("tracker.tracking.reference_matching=") + matching});
  }
  variants.push_back({std::string("optical flow between keyframes ") + (t.flow.enabled ? "off" : "on"),
                      std::string("tracker.tracking.flow.enabled=") + (t.flow.enabled ? "false" : "true")});
  const int threads = t.orb.threads > 1 ? 1 : 2;
  variants.push_back(
      {"extraction threads " + std::to_string(threads), "tracker.tracking.orb.threads=" + std::to_string(threads)});
  const bool worker = !t.keyframe_worker;
  variants.push_back({std::string("keyframe worker ") + (worker ? "on" : "off"),
                      std::string("tracker.tracking.keyframe_worker=") + (worker ? "true" : "false")});
  return variants;
}

// Each variant in a child `stitch bench` (its own peak memory), then the table.
nlohmann::json BenchOptions(const BenchArgs& a) {
  const StitchConfig config = ApplySettings(LoadStitchConfig(a.config_path), a.settings);
  const std::vector<Variant> variants = SpeedVariants(config);
  const std::filesystem::path scratch =
      std::filesystem::temp_directory_path() / ("stitch-bench-" + std::to_string(::getpid()));
  std::filesystem::create_directories(scratch);
  struct RemoveScratch {
    std::filesystem::path path;
    ~RemoveScratch() {
      std::error_code ignored;
      std::filesystem::remove_all(path, ignored);
    }
  } remove_scratch{scratch};  // on failure too
  nlohmann::json all = nlohmann::json::array();
  for (size_t i = 0; i < variants.size(); ++i) {
    const Variant& v = variants[i];
    std::printf("[%zu/%zu] %s ...", i + 1, variants.size(), v.name.c_str());
    std::fflush(stdout);
    const std::string json_path = (scratch / ("variant" + std::to_string(i) + ".json")).string();
    std::vector<std::string> settings = a.settings;
    if (!v.settings.empty()) settings.push_back(v.settings);
    std::vector<std::string> args{"bench", "--json", json_path};
    const std::vector<std::string> source_args =
        SourceArguments(a.source, kDatasetFlag | kCalibFlag | kFailuresFlag | kMaxFramesFlag);
    args.insert(args.end(), source_args.begin(), source_args.end());
    if (!a.config_path.empty()) args.insert(args.end(), {"--config", a.config_path});
    for (const std::string& setting : settings) args.insert(args.end(), {"--set", setting});
    const Stopwatch clock;
    ChildProcess child("bench", ExecutableDir() + "/stitch", args,
                       (scratch / ("variant" + std::to_string(i) + ".log")).string());
    std::optional<int> status;
    while (!(status = child.Poll())) std::this_thread::sleep_for(std::chrono::milliseconds(100));
    if (*status != 0)
      throw Error("variant '" + v.name + "' failed (exit " + std::to_string(*status) + "):\n" + child.LogTail(15));
    std::ifstream in(json_path);
    nlohmann::json result = nlohmann::json::parse(in);
    result["variant"] = v.name;
    std::printf(" %.0f s\n", clock.ElapsedSeconds());
    all.push_back(result);
  }
  std::printf("\n%-34s %9s %7s %6s %8s | %9s %11s %9s %8s %13s %6s %6s\n", "variant", "localized", "submaps", "losses",
              "ATE [m]", "extract", "frame2frame", "local map", "keyframe", "whole frame", "fps", "MB");
  std::printf("%-34s %9s %7s %6s %8s | %9s %11s %9s %8s %13s %6s %6s\n", "", "", "", "", "", "median ms", "median ms",
              "median ms", "p95 ms", "median/p95", "", "peak");
  for (const auto& r : all) {
    const auto& e = r["evaluation"];
    const auto ms = [&](const char* what, const char* stat) { return r["ms"][what][stat].get<double>(); };
    char ate[16] = "n/a";
    if (!e["ate_rmse_m"].is_null()) std::snprintf(ate, sizeof(ate), "%.4f", e["ate_rmse_m"].get<double>());
    std::printf("%-34s %4d/%-4d %7d %6d %8s | %9.2f %11.2f %9.2f %8.2f %6.2f/%-6.2f %6.1f %6.0f\n",
                r["variant"].get<std::string>().c_str(), e["frames_localized"].get<int>(), e["frames_total"].get<int>(),
                e["submaps"].get<int>(), r["losses"].get<int>(), ate, ms("feature extraction", "median"),
                ms("frame-to-frame tracking", "median"), ms("local-map tracking", "median"),
                ms("keyframe decision", "p95"), ms("whole frame", "median"), ms("whole frame", "p95"),
                r["tracking_fps"].get<double>(), r["peak_memory_mb"].get<double>());
  }
  nlohmann::json out;
  out["variants"] = all;
  return out;
}

}  // namespace

int BenchCommand(int argc, char** argv) {
  for (int i = 1; i < argc; ++i) {
    if (std::string(argv[i]) == "--quality") return QualityCommand(argc, argv);
    if (std::string(argv[i]) == "--realtime") return MarginCommand(argc, argv);
  }
  BenchArgs a;
  bool options = false;
  ArgParser args(
      "stitch bench",
      "Times tracking and mapping on a sequence in one process (no bus), lockstep as `stitch run`: "
      "per-frame time of feature extraction, frame-to-frame tracking (motion model, homography or reference "
      "keyframe), local-map tracking, keyframe work, and the whole frame, over frames that were tracked; "
      "tracking losses and accuracy. With --options, once per speed option switched, side by side. "
      "Without --dataset, the synthetic flight without gusts. With --quality, the quality gate (see "
      "stitch bench --quality --help). With --realtime, the margin in real time (see stitch bench --realtime --help).");
  a.source.failures = "none";
  AddSourceOptions(&args, &a.source, kDatasetFlag | kCalibFlag | kFailuresFlag | kMaxFramesFlag);
  args.AddOption("--config", &a.config_path, "FILE",
                 "YAML settings (e.g. synthetic.width: 752 for EuRoC-sized frames)");
  args.AddOption("--set", &a.settings, "KEY=VALUE",
                 "a setting over the configuration, e.g. tracker.tracking.orb.threads=2");
  args.AddFlag(
      "--options", &options,
      "run once per speed option switched (homography tracking and its region of interest, reference "
      "matching, optical flow between keyframes, extraction threads, keyframe worker) and print them side by side");
  args.AddOption("--json", &a.json_path, "FILE", "also write the figures as JSON");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    const nlohmann::json json = options ? BenchOptions(a) : BenchOnce(a);
    if (!a.json_path.empty()) {
      WriteFileAtomically(a.json_path, json.dump(2) + "\n");
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch bench: %s\n", e.what());
    return 1;
  }
}

}  // namespace stitch
