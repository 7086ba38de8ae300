// stitch run: starts the services as separate processes on a bus of their own, plays a
// sequence through them, shows progress, shuts them down, and writes the run's outputs. The
// parts: launch/launch_plan.h (what starts, with which arguments), launch/run_services.h (the
// processes), launch/run_monitor.h (the watch over the flight), launch/run_outputs.h.

#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <thread>

#include <nlohmann/json.hpp>

#include "services/common/bus.h"
#include "services/common/service.h"
#include "stitch/util/text_file.h"
#include "stitch/util/time.h"
#include "tools/stitch/commands.h"
#include "tools/stitch/launch/launch_plan.h"
#include "tools/stitch/launch/run_monitor.h"
#include "tools/stitch/launch/run_outputs.h"
#include "tools/stitch/launch/run_services.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

// One run's outcome, for the comparison table.
struct RunOutcome {
  int exit_code = 0;
  std::optional<Evaluation> evaluation;
  std::string out;
  std::string on_loss;
};

std::string NewRunFolder() {
  const std::string base = "runs/" + LocalTimestamp("%Y%m%d-%H%M%S");
  std::string path = base;
  for (int n = 2; fs::exists(path); ++n) path = base + "-" + std::to_string(n);
  return path;
}

// Plans the run, starts the services, watches the flight, stops the services and writes the
// outputs (docs/architecture.md, "stitch run").
RunOutcome RunOnce(const RunArgs& a, const std::string& out) {
  RunOutcome outcome;
  outcome.out = out;
  // Ctrl-C is caught from the start: during the set-up (a long synthetic flight takes seconds to
  // plan) it ends the run before the services start, with its outputs as after any interruption.
  const auto& stop = InstallStopSignals();
  LaunchPlan plan;
  std::unique_ptr<SplitNetwork> network;
  std::unique_ptr<lcm::LCM> lcm;
  std::optional<bus::BusAuthenticator> authenticator;  // the bus key's (bus.key_file), for the monitor
  try {
    plan = PlanRun(a, out);
    authenticator = bus::BusAuthenticator::FromSetting(plan.config.bus.key_file);
    outcome.on_loss = plan.config.tracker.on_loss;
    PrepareRunFolder(plan);
    if (plan.netns) network = std::make_unique<SplitNetwork>((fs::path(out) / "logs" / "netns.log").string());
    if (network) network->EnterAircraft();  // the launcher listens on the aircraft's side
    lcm = bus::OpenLcm(plan.url);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch run: %s\n", e.what());
    outcome.exit_code = 2;
    return outcome;
  }
  RunInfo& info = plan.info;
  std::printf("stitch run: %s\n  on-loss %s, %s pacing, bus %s\n", info.source.c_str(), info.on_loss.c_str(),
              info.pacing.c_str(), plan.url.c_str());
  if (plan.linked) std::printf("  merger on %s behind a link: %s\n", plan.ground_url.c_str(), info.link.c_str());
  if (network) std::printf("  %s\n", network->Describe().c_str());
  std::printf("  output %s/\n", out.c_str());
  const std::string viewer_address = ViewerAddress(plan);
  if (!viewer_address.empty()) std::printf("  viewer %s\n", viewer_address.c_str());
  std::fflush(stdout);

  RunMonitor monitor(lcm.get(), a.agent, authenticator);
  bus::Dispatcher dispatcher(lcm.get());
  dispatcher.Start();
  const Stopwatch clock;
  RunServices services(plan, network.get());
  std::string failure;
  try {
    if (!stop.load()) services.StartAll();
    failure = WatchFlight(plan, monitor, services, stop, a.quiet, &info);
  } catch (const std::exception& e) {
    failure = e.what();
  }
  // Upstream first: each drains its queue and writes its files on SIGTERM. The viewer stays up
  // after a flight that ended well: it shows the finished flight.
  const bool ended_well = !info.interrupted && failure.empty();
  const std::string stop_failure = services.StopAll(/*keep_viewer=*/ended_well, /*quiet_statuses=*/!ended_well);
  if (failure.empty()) failure = stop_failure;
  dispatcher.Stop();
  info.wall_seconds = clock.ElapsedSeconds();
  services.Report(&info);
  int exit_code = 0;
  if (!failure.empty()) {
    std::fprintf(stderr, "stitch run: %s\n", failure.c_str());
    info.notes.push_back("the run failed: " + failure);
    exit_code = 1;
  }
  // The ground's per-frame trajectory (the merger's, from the pose stream, written during the
  // flight) stays beside the one the run ends with, which re-composes frames.tsv with the mapper's
  // final keyframes (every frame, culled keyframes included).
  if (fs::exists(fs::path(out) / "trajectory.tum")) {
    std::error_code ignored;
    fs::rename(fs::path(out) / "trajectory.tum", fs::path(out) / "trajectory_ground.tum", ignored);
  }
  try {
    const Evaluation evaluation = FinishRunOutputs(out, &info);
    SaveRunInfo(info, out);
    PrintRunSummary(info, Summarize(evaluation), out, exit_code);
    outcome.evaluation = evaluation;
    ChildProcess* viewer = services.Find("viewer");
    if (viewer && !viewer->Poll() && !stop.load()) {
      std::printf("viewer: %s shows the finished flight; Ctrl-C ends it\n", viewer_address.c_str());
      std::fflush(stdout);
      while (!stop.load() && !viewer->Poll()) std::this_thread::sleep_for(std::chrono::milliseconds(100));
      viewer->Terminate(std::chrono::milliseconds(5000));
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch run: writing the outputs failed: %s\n", e.what());
    outcome.exit_code = 1;
    return outcome;
  }
  outcome.exit_code = info.interrupted ? 130 : exit_code;
  return outcome;
}

// Frames with a pose in any submap (before merging).
int FramesPosedInAnySubmap(const Evaluation& e) {
  int frames = 0;
  for (const auto& submap : e.per_submap) frames += submap.frames;
  return frames;
}

std::string FormatComparison(const std::vector<RunOutcome>& runs) {
  std::string text = "\ncomparison (same sequence and failures)\n";
  char line[256];
  std::snprintf(line, sizeof(line), "  %-34s", "");
  text += line;
  for (const auto& run : runs) {
    std::snprintf(line, sizeof(line), "%22s", ("--on-loss " + run.on_loss).c_str());
    text += line;
  }
  text += "\n";
  const auto row = [&](const char* name, const std::function<std::string(const Evaluation&)>& value) {
    std::snprintf(line, sizeof(line), "  %-34s", name);
    text += line;
    for (const auto& run : runs) {
      std::snprintf(line, sizeof(line), "%22s", run.evaluation ? value(*run.evaluation).c_str() : "failed");
      text += line;
    }
    text += "\n";
  };
  const auto format = [](const char* f, auto... v) {
    char buffer[64];
    std::snprintf(buffer, sizeof(buffer), f, v...);
    return std::string(buffer);
  };
  row("frames localized (largest map)",
      [&](const Evaluation& e) { return format("%d (%.1f%%)", e.frames_localized, 100.0 * e.completeness); });
  row("frames posed in any submap", [&](const Evaluation& e) { return format("%d", FramesPosedInAnySubmap(e)); });
  row("usable frames", [&](const Evaluation& e) { return format("%d", e.frames_total - e.frames_unusable); });
  row("keyframes retained", [&](const Evaluation& e) { return format("%d", e.keyframes); });
  row("submaps (merged in the largest)",
      [&](const Evaluation& e) { return format("%d (%d)", e.submaps, e.submaps_merged); });
  row("ATE RMSE, largest map",
      [&](const Evaluation& e) { return e.errors ? format("%.4f m", e.errors->ate_rmse_m) : std::string("n/a"); });
  row("tracking time median", [&](const Evaluation& e) {
    return e.tracking_ms_median ? format("%.1f ms", *e.tracking_ms_median) : std::string("n/a");
  });
  return text;
}

}  // namespace

int RunCommand(int argc, char** argv) {
  RunArgs a;
  ArgParser args("stitch run",
                 "Runs stitch on a sequence: ingest, tracker, mapper and merger as separate processes over LCM, then "
                 "evaluates the result. Without --dataset it flies the embedded "
                 "synthetic UAV survey with 3 scheduled gusts.");
  AddSourceOptions(&args, &a.source);
  args.AddOption("--out", &a.out, "DIR", "output folder, new or empty (default: a new folder under runs/)");
  args.AddOption("--on-loss", &a.on_loss, "MODE", "submap (stitch, default) or relocalize (ORB-SLAM2-like baseline)");
  args.AddOption("--config", &a.config_path, "FILE", "YAML settings (print the defaults with `stitch config`)");
  args.AddOption("--set", &a.settings, "KEY=VALUE",
                 "a setting over the file, e.g. tracker.tracking.orb.num_features=1500");
  args.AddOption("--vocabulary", &a.vocabulary, "FILE",
                 "bag-of-words vocabulary (a stitch vocabulary, or DBoW2 text such as ORB-SLAM's ORBvoc.txt; "
                 "default: the one shipped)");
  args.AddOption("--map", &a.map, "FILE",
                 "a saved map (map.stitchmap of an earlier run, or `stitch map save`): the flight's submaps merge "
                 "into it and its frame is the merged map's (merger.prior_map)");
  args.AddFlag("--localize-only", &a.localize_only,
               "with --map: track in the saved map only, without mapping (no keyframe, no submap of this flight)");
  args.AddOption("--pacing", &a.pacing, "MODE", "lockstep (reproducible, default) or realtime");
  args.AddOption("--lcm-url", &a.lcm_url, "URL", "bus for the services (default: a random local port, ttl=0)");
  args.AddOption("--agent", &a.agent, "NAME", "agent name prefixing the channels");
  args.AddOption("--log-level", &a.log_level, "LEVEL", "services' log level: debug, info, warning, error");
  args.AddFlag("--quiet", &a.quiet, "no progress line");
  args.AddFlag("--journal", &a.journal,
               "keep the merger's journal of submap updates in DIR/merger (about 73 MB for the default flight); "
               "`stitch map` rebuilds the merged map from it");
  args.AddFlag("--link", &a.link,
               "rehearse the radio link: the merger on a bus of its own, reached through a pair of link bridges "
               "(stitch-link) with the config's link settings");
  args.AddFlag("--netns", &a.netns,
               "with --link: the aircraft's and the ground's services in two network namespaces joined by a veth "
               "pair (needs root and iproute2)");
  args.AddOption("--link-loss", &a.link_loss, "P", "with --link: drop each datagram with probability P (link.loss)");
  args.AddOption("--link-delay-ms", &a.link_delay_ms, "MS", "with --link: delay each datagram (link.delay_ms)");
  args.AddOption("--link-budget", &a.link_budget, "BYTES/S",
                 "with --link: bandwidth budget of each side (link.budget_bytes_per_s; 0: none)");
  args.AddFlag("--viewer", &a.viewer,
               "serve the ground's live web page (stitch-viewer, http://127.0.0.1:8080/) during the flight, and "
               "after it until Ctrl-C");
  args.AddOption("--viewer-port", &a.viewer_port, "PORT", "with --viewer: its TCP port (viewer.port)");
  args.AddFlag(
      "--compare", &a.compare,
      "run twice, --on-loss submap then relocalize, into DIR/submap and DIR/relocalize, and print both side by side");
  args.AddEpilog(
      "Outputs: trajectory.tum, map.ply (the largest merged map without gross outliers; map_raw.ply\n"
      "with every point), trajectories/ (every map, index.tsv), trajectory_kitti.txt (KITTI input),\n"
      "report.json, trajectory.png,\n"
      "frames.tsv, poses.tsv, memory.tsv (each service's resident memory every 2 s), groundtruth.tum (when known), "
      "config.yaml (resolved settings), the\n"
      "merger's graph.png, graph.dot, merge_log.tsv, retrieval.tsv, submaps.tsv, keyframes_merged.tsv,\n"
      "the mapper's keyframes.tsv and submaps.ply, map.stitchmap (the largest merged map, for --map), logs/ (one\n"
      "per service); with --journal,\n"
      "merger/submap_updates.lcmlog.");
  if (!args.Parse(argc, argv)) return args.exit_code();

  if (!a.link && !a.netns && (a.link_loss >= 0 || a.link_delay_ms >= 0 || a.link_budget >= 0)) {
    std::fprintf(stderr, "stitch run: --link-loss, --link-delay-ms and --link-budget need --link\n");
    return 2;
  }
  if (a.localize_only && a.map.empty()) {
    std::fprintf(stderr, "stitch run: --localize-only needs --map FILE\n");
    return 2;
  }
  if (a.viewer && a.compare) {
    std::fprintf(stderr, "stitch run: --viewer shows one run; give it without --compare\n");
    return 2;
  }
  if (a.viewer_port >= 0 && !a.viewer) {
    std::fprintf(stderr, "stitch run: --viewer-port needs --viewer\n");
    return 2;
  }
  const std::string out = a.out.empty() ? NewRunFolder() : a.out;
  if (!a.compare) return RunOnce(a, out).exit_code;
  if (!a.on_loss.empty()) {
    std::fprintf(stderr, "stitch run: --compare runs both --on-loss modes; do not give --on-loss\n");
    return 2;
  }
  std::vector<RunOutcome> runs;
  for (const char* mode : {"submap", "relocalize"}) {
    RunArgs one = a;
    one.on_loss = mode;
    runs.push_back(RunOnce(one, (fs::path(out) / mode).string()));
    if (runs.back().exit_code == 2 || runs.back().exit_code == 130) return runs.back().exit_code;
  }
  const std::string table = FormatComparison(runs);
  std::printf("%s", table.c_str());
  nlohmann::json j = nlohmann::json::array();
  for (const auto& run : runs) {
    j.push_back({{"on_loss", run.on_loss},
                 {"out", run.out},
                 {"exit_code", run.exit_code},
                 {"report", run.evaluation ? ToJson(*run.evaluation) : nlohmann::json()}});
  }
  try {
    WriteFileAtomically((fs::path(out) / "comparison.txt").string(), table);
    WriteFileAtomically((fs::path(out) / "comparison.json").string(), j.dump(2) + "\n");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch run: writing the comparison failed: %s\n", e.what());
    return 1;
  }
  std::printf("comparison written to %s/comparison.{txt,json}\n", out.c_str());
  for (const auto& run : runs) {
    if (run.exit_code != 0) return run.exit_code;
  }
  return 0;
}

}  // namespace stitch
