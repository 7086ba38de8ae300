// stitch bench: times the SLAM core on a sequence, without the bus: per-frame time of each
// tracking step (median and 95th percentile over tracked frames), frames per second, mapping
// time per keyframe, peak memory, and the accuracy of the run. Pin it to one core with
// `taskset -c 0 build/bin/stitch bench` to measure what one core of a small onboard computer gets.

#include <sys/resource.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "services/config/stitch_config.h"
#include "services/pipeline/inline_pipeline.h"
#include "stitch/source/source.h"
#include "stitch/util/args.h"
#include "stitch/util/error.h"
#include "stitch/util/time.h"
#include "tools/stitch/commands.h"

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

}  // namespace

int BenchCommand(int argc, char** argv) {
  std::string dataset, config_path, failures = "none", json_path, calibration;
  int max_frames = -1;
  ArgParser args("stitch bench",
                 "Times tracking and mapping on a sequence in one process (no bus), lockstep as `stitch run`: "
                 "per-frame time of feature extraction, frame-to-frame tracking (motion model or reference "
                 "keyframe), local-map tracking, keyframe work, and the whole frame, over frames that were tracked. "
                 "Without --dataset, the synthetic flight without gusts.");
  args.AddOption("--dataset", &dataset, "PATH", "sequence to time (default: the synthetic flight)");
  args.AddOption("--calib", &calibration, "FILE", "calibration overriding the dataset's own");
  args.AddOption("--config", &config_path, "FILE", "YAML settings (e.g. synthetic.width: 752 for EuRoC-sized frames)");
  args.AddOption("--failures", &failures, "SPEC", "induced failures");
  args.AddOption("--max-frames", &max_frames, "N", "time at most N frames");
  args.AddOption("--json", &json_path, "FILE", "also write the figures as JSON");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    const StitchConfig config = LoadStitchConfig(config_path);
    const Vocabulary vocabulary = LoadVocabulary(config);
    SourceSpec spec;
    spec.dataset_path = dataset;
    spec.calibration_path = calibration;
    spec.failures = failures;
    spec.max_frames = max_frames;
    spec.synthetic = config.synthetic;
    FailureSchedule spoil;
    auto sequence = OpenSource(spec, &spoil);
    if (!spoil.empty()) throw Error("stitch bench applies failure schedules to the synthetic flight only");
    std::printf("stitch bench: %s, %dx%d\n", sequence->description().c_str(), sequence->camera().width(),
                sequence->camera().height());
    const Stopwatch clock;
    int done = 0;
    const InlineRun run = RunInline(*sequence, config, vocabulary, [&](const InlineFrame&) {
      if (++done % 100 == 0) {
        std::printf("\r  %d frames", done);
        std::fflush(stdout);
      }
    });
    std::printf("\r  %d frames in %.1f s\n", done, clock.ElapsedSeconds());
    std::vector<double> extraction, frame_to_frame, local_map, keyframe, total, all_frames, mapping;
    for (const InlineFrame& f : run.frames) {
      all_frames.push_back(f.result.timings.total);
      if (f.mapping_ms > 0) mapping.push_back(f.mapping_ms);
      if (f.result.state != TrackingState::kOk || f.result.timings.local_map == 0) continue;
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
    std::printf("\n  per tracked frame (%zu frames)   median     p95    mean   [ms]\n", total.size());
    const std::pair<const char*, const std::vector<double>*> rows[] = {
        {"feature extraction", &extraction}, {"frame-to-frame tracking", &frame_to_frame},
        {"local-map tracking", &local_map},  {"keyframe decision", &keyframe},
        {"whole frame", &total},             {"every frame (any state)", &all_frames},
        {"mapping, per keyframe", &mapping}};
    for (const auto& [name, values] : rows) {
      const Stat s = Summarize(*values);
      std::printf("  %-32s %7.2f %7.2f %7.2f\n", name, s.median, s.p95, s.mean);
      json["ms"][name] = {{"median", s.median}, {"p95", s.p95}, {"mean", s.mean}, {"count", s.count}};
    }
    const Stat frame_stat = Summarize(all_frames);
    const double fps = frame_stat.mean > 0 ? 1000.0 / frame_stat.mean : 0;
    std::printf("  tracking throughput %.1f frames/s (tracker alone), peak memory %.0f MB\n", fps, peak_mb);
    std::printf("%s", stitch::Summarize(evaluation).c_str());
    json["tracking_fps"] = fps;
    json["peak_memory_mb"] = peak_mb;
    json["evaluation"] = ToJson(evaluation);
    if (!json_path.empty()) std::ofstream(json_path) << json.dump(2) << "\n";
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch bench: %s\n", e.what());
    return 1;
  }
}

}  // namespace stitch
