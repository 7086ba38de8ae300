// stitch run: starts the services as separate processes on a bus of their own, plays a
// sequence through them, shows progress, shuts them down, and writes the run's outputs.

#include <unistd.h>

#include <cmath>
#include <csignal>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <functional>
#include <mutex>
#include <optional>
#include <random>
#include <thread>

#include "services/common/bus.h"
#include "services/common/service.h"
#include "services/config/stitch_config.h"
#include "services/link/link_auth.h"
#include "stitch/sequence_info_t.hpp"
#include "stitch/source/source.h"
#include "stitch/tracking_status_t.hpp"
#include "stitch/util/child_process.h"
#include "stitch/util/ids.h"
#include "stitch/util/options.h"
#include "stitch/util/text_file.h"
#include "tools/stitch/commands.h"
#include "tools/stitch/run_outputs.h"
#include "tools/stitch/split_network.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

// How often the launcher writes each service's resident memory to memory.tsv.
constexpr double kMemorySampleSeconds = 2.0;

struct RunArgs {
  std::string dataset;
  std::string live;  // a live camera's URI (stitch-ingest --live)
  std::string out;
  std::string failures = "default";
  std::string on_loss;
  std::string config_path;
  std::string calibration;
  std::string lcm_url;
  std::string pacing;
  std::string agent = "uav0";
  std::string log_level = "info";
  int max_frames = -1;
  int start_frame = 0;
  std::string vocabulary;  // over the settings' vocabulary
  bool quiet = false;
  bool journal = false;  // keep the merger's journal in OUT/merger
  bool compare = false;
  bool viewer = false;   // the ground's live web page (stitch-viewer), kept up after the flight
  int viewer_port = -1;  // < 0: viewer.port
  bool link = false;     // a link bridge pair between the aircraft's bus and the ground's
  bool netns = false;    // and the two sides in two network namespaces
  double link_loss = -1, link_delay_ms = -1, link_budget = -1;  // < 0: as configured
  std::vector<std::string> settings;                            // --set KEY=VALUE
};

// One run's outcome, for the comparison table.
struct RunOutcome {
  int exit_code = 0;
  std::optional<Evaluation> evaluation;
  std::string out;
  std::string on_loss;
};

// What the launcher hears on the bus, for progress and for knowing when the tracker is done.
class RunMonitor {
 public:
  RunMonitor(lcm::LCM* lcm, const std::string& agent) : subscriber_(lcm) {
    subscriber_.Subscribe<stitch::tracking_status_t>(
        bus::Channel(agent, bus::kTrackingStatus),
        [this](std::unique_ptr<stitch::tracking_status_t> s, const std::string&) {
          std::lock_guard<std::mutex> lock(mutex_);
          if (s->frame_index > highest_frame_) {
            highest_frame_ = s->frame_index;
            latest_ = *s;
          }
          ++statuses_;
          last_change_ = MonotonicSeconds();
        });
    subscriber_.Subscribe<stitch::service_status_t>(
        bus::Channel(agent, bus::kService), [this](std::unique_ptr<stitch::service_status_t> s, const std::string&) {
          std::lock_guard<std::mutex> lock(mutex_);
          services_[s->service] = *s;
        });
  }

  struct Snapshot {
    int highest_frame = -1;
    int64_t statuses = 0;
    stitch::tracking_status_t latest{};
    double last_change = 0;
    std::map<std::string, stitch::service_status_t> services;
  };
  Snapshot Get() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return {highest_frame_, statuses_, latest_, last_change_, services_};
  }

 private:
  bus::Subscriber subscriber_;
  mutable std::mutex mutex_;
  int highest_frame_ = -1;
  int64_t statuses_ = 0;
  stitch::tracking_status_t latest_{};
  double last_change_ = MonotonicSeconds();
  std::map<std::string, stitch::service_status_t> services_;
};

const char* StateName(int8_t state) {
  switch (state) {
    case stitch::tracking_status_t::STATE_INITIALIZING:
      return "INITIALIZING";
    case stitch::tracking_status_t::STATE_OK:
      return "OK";
    case stitch::tracking_status_t::STATE_LOST:
      return "LOST";
    case stitch::tracking_status_t::STATE_SKIPPED:
      return "SKIPPED";
    default:
      return "NOT_TRACKED";
  }
}

std::string NewRunFolder() {
  const std::string base = "runs/" + LocalTimestamp("%Y%m%d-%H%M%S");
  std::string path = base;
  for (int n = 2; fs::exists(path); ++n) path = base + "-" + std::to_string(n);
  return path;
}

RunOutcome RunOnce(const RunArgs& a, const std::string& out) {
  RunOutcome outcome;
  outcome.out = out;
  RunInfo info;
  StitchConfig config;
  SourceSummary source;
  SourceSpec spec;
  try {
    bus::CheckAgentName(a.agent);
    // The launcher's own flags are settings like --set's, over the file.
    std::vector<std::string> settings = a.settings;
    if (a.start_frame < 0) throw Error("--start-frame must be >= 0");
    if (!a.vocabulary.empty() && !fs::is_regular_file(a.vocabulary)) {
      throw Error(a.vocabulary + ": no such vocabulary file (--vocabulary)");
    }
    if (!a.pacing.empty()) settings.push_back(TextSetting("ingest.pacing", a.pacing));
    if (!a.on_loss.empty()) settings.push_back(TextSetting("tracker.on_loss", a.on_loss));
    if (a.link_loss >= 0) settings.push_back(NumberSetting("link.loss", a.link_loss));
    if (a.link_delay_ms >= 0) settings.push_back(NumberSetting("link.delay_ms", a.link_delay_ms));
    if (a.link_budget >= 0) settings.push_back(NumberSetting("link.budget_bytes_per_s", a.link_budget));
    const std::vector<std::string> from_calibration =
        a.calibration.empty() ? std::vector<std::string>() : OrbSlamFeatureSettings(a.calibration);
    for (const std::string& setting : from_calibration) {
      info.notes.push_back("from the ORB-SLAM settings " + a.calibration + ": " + setting);
    }
    config = LoadStitchConfig(a.config_path, CommandLineSettings(a.calibration, a.vocabulary, settings));
    spec.dataset_path = a.dataset;
    spec.live_uri = a.live.empty() && a.dataset.empty() ? config.ingest.live : a.live;  // the config may name it
    spec.calibration_path = a.calibration;
    spec.failures = a.failures;
    spec.max_frames = a.max_frames;
    spec.start_frame = a.start_frame;
    spec.synthetic = config.synthetic;
    source = SummarizeSource(spec);
    if (source.num_frames == 0) throw Error("the sequence has no frames");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch run: %s\n", e.what());
    outcome.exit_code = 2;
    return outcome;
  }
  outcome.on_loss = config.tracker.on_loss;

  const bool linked = a.link || a.netns;
  const std::string url = a.lcm_url.empty() ? bus::UnusedLocalUdpUrl() : a.lcm_url;
  // With a link, the merger is on a bus of its own, reached only through the bridges.
  std::string ground_url = url;
  if (linked) {
    do ground_url = bus::UnusedLocalUdpUrl();
    while (ground_url == url);
    char text[160];
    std::snprintf(text, sizeof(text), "loss %g, delay %g ms, jitter %g ms, budget %s%s", config.link.loss,
                  config.link.delay_ms, config.link.jitter_ms,
                  config.link.budget_bytes_per_s > 0
                      ? (std::to_string(static_cast<int64_t>(config.link.budget_bytes_per_s)) + " B/s").c_str()
                      : "none",
                  a.netns ? ", two network namespaces" : ", loopback");
    info.link =
        std::string(text) +
        (config.link.insecure && config.link.key_file.empty() ? ", unauthenticated (insecure)" : ", authenticated");
  }
  info.source = source.description;
  info.dataset = a.dataset;
  info.start_frame = a.start_frame;
  info.frames_total = source.num_frames;
  info.frames_unusable = source.num_frames < 0 ? 0 : source.failures.CountWithin(source.num_frames);
  info.failures = source.failures.ToString();
  info.on_loss = config.tracker.on_loss;
  info.pacing = spec.live_uri.empty() ? config.ingest.pacing : "live";
  info.lcm_url = url;
  info.agent = a.agent;
  info.started_at = LocalTimestamp("%Y-%m-%dT%H:%M:%S%z");

  std::unique_ptr<lcm::LCM> lcm;
  std::unique_ptr<SplitNetwork> network;
  try {
    // A run never writes over another run's records (the tracker appends to frames.tsv).
    if (fs::exists(out) && !fs::is_empty(out)) {
      throw Error(out + " exists and is not empty; give --out a new folder (or remove that one)");
    }
    fs::create_directories(fs::path(out) / "logs");
    SaveStitchConfig(config, (fs::path(out) / "config.yaml").string());
    if (!source.ground_truth.empty()) source.ground_truth.WriteTum((fs::path(out) / "groundtruth.tum").string());
    SaveRunInfo(info, out);
    if (a.netns) {
      network = std::make_unique<SplitNetwork>((fs::path(out) / "logs" / "netns.log").string());
      network->EnterAircraft();  // this launcher listens on the aircraft's side
    }
    lcm = bus::OpenLcm(url);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch run: %s\n", e.what());
    outcome.exit_code = 2;
    return outcome;
  }

  std::printf("stitch run: %s\n  on-loss %s, %s pacing, bus %s\n", source.description.c_str(), info.on_loss.c_str(),
              info.pacing.c_str(), url.c_str());
  if (linked) std::printf("  merger on %s behind a link: %s\n", ground_url.c_str(), info.link.c_str());
  if (network) std::printf("  %s\n", network->Describe().c_str());
  std::printf("  output %s/\n", out.c_str());
  std::fflush(stdout);

  const auto& stop = InstallStopSignals();
  RunMonitor monitor(lcm.get(), a.agent);
  bus::Dispatcher dispatcher(lcm.get());
  dispatcher.Start();

  const std::string bin = ExecutableDir();
  const std::string config_file = (fs::path(out) / "config.yaml").string();
  const auto common_on = [&](const std::string& bus_url) {
    return std::vector<std::string>{"--lcm-url", bus_url,     "--agent",     a.agent,
                                    "--config",  config_file, "--log-level", a.log_level};
  };
  const std::vector<std::string> common = common_on(url), ground_common = common_on(ground_url);
  const Stopwatch clock;
  int exit_code = 0;
  std::string failure;
  std::vector<std::unique_ptr<ChildProcess>> children;
  const auto start = [&](const std::string& name, const std::string& program, std::vector<std::string> args) {
    children.push_back(std::make_unique<ChildProcess>(name, bin + "/" + program, args,
                                                      (fs::path(out) / "logs" / (name + ".log")).string()));
    return children.back().get();
  };
  const auto with = [](std::vector<std::string> args, const std::vector<std::string>& more) {
    args.insert(args.end(), more.begin(), more.end());
    return args;
  };
  ChildProcess *merger = nullptr, *mapper = nullptr, *tracker = nullptr, *ingest = nullptr, *viewer = nullptr;
  const int viewer_port = a.viewer_port >= 0 ? a.viewer_port : config.viewer.port;
  const std::string viewer_url = "http://" + config.viewer.bind_address + ":" + std::to_string(viewer_port) + "/";
  std::vector<ChildProcess*> links;
  try {
    std::vector<std::string> merger_args = with(ground_common, {"--record", out});
    if (a.journal) merger_args = with(merger_args, {"--state", (fs::path(out) / "merger").string()});
    if (network) network->EnterGround();
    if (linked) {
      const std::string air = network ? SplitNetwork::kAircraftAddress : "127.0.0.1";
      const std::string ground = network ? SplitNetwork::kGroundAddress : "127.0.0.1";
      const std::vector<int> link_ports = bus::UnusedUdpPorts(2);
      const std::string air_port = std::to_string(link_ports[0]), ground_port = std::to_string(link_ports[1]);
      merger = start("merger", "stitch-merger", merger_args);
      const std::string aircraft_sends = a.agent + "/(SUBMAP|SEQUENCE|TRACKING_STATUS|POSE|SERVICE|LINK_STATUS)";
      // Authenticated as deployed: the config's key, else one made for this run (beside its outputs).
      std::vector<std::string> key;
      if (!config.link.key_file.empty()) {
        key = {"--key", config.link.key_file};
      } else if (!config.link.insecure) {
        const std::string run_key = (fs::path(out) / "link.key").string();
        link::GenerateKeyFile(run_key);
        key = {"--key", run_key};
      }
      std::vector<std::string> ground_link =
          with(with(ground_common, {"--forward", a.agent + "/" + bus::kSubmapRequest, "--accept", aircraft_sends,
                                    "--listen", ground + ":" + ground_port, "--peer", air + ":" + air_port}),
               key);
      links.push_back(start("link-ground", "stitch-link", ground_link));
      if (network) network->EnterAircraft();
      links.push_back(
          start("link-aircraft", "stitch-link",
                with(with(common, {"--forward", aircraft_sends, "--accept", a.agent + "/" + bus::kSubmapRequest,
                                   "--listen", air + ":" + air_port, "--peer", ground + ":" + ground_port}),
                     key)));
    } else {
      merger = start("merger", "stitch-merger", merger_args);
    }
    if (a.viewer) {
      viewer = start("viewer", "stitch-viewer", with(ground_common, {"--port", std::to_string(viewer_port)}));
      std::printf("  viewer %s\n", viewer_url.c_str());
      std::fflush(stdout);
    }
    mapper = start("mapper", "stitch-mapper", with(common, {"--record", out}));
    tracker = start("tracker", "stitch-tracker",
                    with(common, {"--record", (fs::path(out) / "frames.tsv").string(), "--state",
                                  (fs::path(out) / "logs" / "tracker.state").string()}));
    std::vector<std::string> ingest_args =
        with(common, {"--failures", a.failures, "--max-frames", std::to_string(a.max_frames), "--start-frame",
                      std::to_string(a.start_frame)});
    if (!a.dataset.empty()) ingest_args = with(ingest_args, {"--dataset", a.dataset});
    if (!spec.live_uri.empty()) ingest_args = with(ingest_args, {"--live", spec.live_uri});
    if (!a.calibration.empty()) ingest_args = with(ingest_args, {"--calib", a.calibration});
    ingest = start("ingest", "stitch-ingest", ingest_args);
  } catch (const std::exception& e) {
    failure = e.what();
  }

  // Progress until ingest has played everything and the tracker has caught up.
  const bool tty = isatty(STDOUT_FILENO) && !a.quiet;
  int last_decile = 0;
  double ingest_done_at = -1;
  const int last_frame = source.num_frames - 1;
  // Each service's resident memory every few seconds, with the frame the tracker was at.
  std::ofstream memory_samples(fs::path(out) / "memory.tsv");
  memory_samples << "seconds\tframe\tservice\trss_mb\n";
  double memory_sampled_at = -1e9;
  while (failure.empty()) {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    const auto snapshot = monitor.Get();
    const int done = snapshot.highest_frame + 1;
    const double seconds = clock.ElapsedSeconds();
    if (seconds - memory_sampled_at >= kMemorySampleSeconds) {
      memory_sampled_at = seconds;
      for (const auto& child : children) {
        const double mb = child->ResidentMb();
        if (mb < 0) continue;
        char row[160];
        std::snprintf(row, sizeof(row), "%.1f\t%d\t%s\t%.1f\n", seconds, snapshot.highest_frame, child->name().c_str(),
                      mb);
        memory_samples << row;
      }
      memory_samples.flush();
    }
    const double fps = seconds > 0 ? done / seconds : 0;
    if (tty) {
      std::printf("\r  frame %5d/%d  %5.1f fps  tracker %-12s submap %-6s keyframes %d   ", done, source.num_frames,
                  fps, snapshot.statuses ? StateName(snapshot.latest.state) : "starting",
                  SubmapName(SubmapId(snapshot.latest.submap_id)).c_str(), snapshot.latest.submap_keyframes);
      std::fflush(stdout);
    } else if (!a.quiet && source.num_frames > 0 && done * 10 / source.num_frames > last_decile) {
      last_decile = done * 10 / source.num_frames;
      std::printf("  frame %d/%d, %.1f fps\n", done, source.num_frames, fps);
      std::fflush(stdout);
    }
    if (stop.load()) {
      info.interrupted = true;
      break;
    }
    std::vector<ChildProcess*> services = links;
    services.insert(services.end(), {merger, mapper, tracker, viewer});
    for (ChildProcess* service : services) {
      if (service && service->Poll()) {
        failure = "the " + service->name() + " exited unexpectedly (status " + std::to_string(*service->Poll()) +
                  "); end of " + service->log_path() + ":\n" + service->LogTail(8);
      }
    }
    if (!failure.empty()) break;
    if (ingest && ingest->Poll() && ingest_done_at < 0) {
      if (*ingest->Poll() != 0) {
        failure = "ingest failed (status " + std::to_string(*ingest->Poll()) + "); end of " + ingest->log_path() +
                  ":\n" + ingest->LogTail(8);
        break;
      }
      ingest_done_at = seconds;
    }
    if (ingest_done_at >= 0) {
      // Ingest has finished; the tracker is done once it has reported the last frame, or has been
      // quiet for a while (frames lost on the way never come).
      const bool caught_up = snapshot.highest_frame >= last_frame;
      const bool quiet = MonotonicSeconds() - snapshot.last_change > 3.0 && seconds - ingest_done_at > 3.0;
      if (caught_up || quiet) break;
    }
  }
  if (tty) std::printf("\n");

  // Shut the services down, upstream first: each drains its queue and writes its files on SIGTERM
  // (the mapper may still have keyframes to map, the aircraft's bridge submap states to deliver,
  // the merger submap updates to merge).
  // Their grace follows their own settings: the mapper waits for its link bridge to catch up and
  // for the merger's last requests, a bridge sends what waits for up to link.max_queue_s. The
  // merger refines the last closed submap's map and then once more at the end: on a 20 km survey
  // each takes a minute or more (its journal keeps what it received; the kill only cost the final
  // map files and made the run fail).
  const double mapper_grace_s = std::max(120.0, config.mapper.stop_link_drain_s + config.mapper.stop_linger_s + 60.0);
  const double link_grace_s = std::max(120.0, config.link.max_queue_s + 65.0);
  for (auto it = children.rbegin(); it != children.rend(); ++it) {
    if (it->get() == viewer && !info.interrupted && failure.empty()) continue;  // it shows the finished flight
    const std::string& name = (*it)->name();
    const double grace_s = name == "mapper"             ? mapper_grace_s
                           : name.rfind("link", 0) == 0 ? link_grace_s
                           : name == "merger"           ? 600.0
                                                        : 15.0;
    const int status = (*it)->Terminate(std::chrono::milliseconds(static_cast<int64_t>(grace_s * 1000)));
    if (status != 0 && status != 128 + SIGTERM && status != 130 && !info.interrupted && failure.empty()) {
      failure = (*it)->name() + " ended with status " + std::to_string(status) + "; see " + (*it)->log_path();
    }
  }
  dispatcher.Stop();
  info.wall_seconds = clock.ElapsedSeconds();
  for (const auto& child : children) {
    if (child->Poll()) info.peak_rss_mb[child->name()] = child->peak_resident_mb();
  }
  for (const ChildProcess* link : links) {
    const std::string tail = link->LogTail(3);
    const size_t said = tail.rfind("stopped: ");
    if (said != std::string::npos) {
      info.link_figures.push_back(link->name() + ": " + tail.substr(said + 9, tail.find('\n', said) - said - 9));
    }
  }

  // What a service logged as an error (a record it could not write on a full disk, updates it had
  // to drop) is said here too, not only in its log.
  for (const auto& child : children) {
    int total = 0;
    const std::vector<std::string> errors = child->LogErrors(3, &total);
    for (const std::string& line : errors) {
      std::fprintf(stderr, "stitch run: the %s logged: %s\n", child->name().c_str(), line.c_str());
      info.notes.push_back("the " + child->name() + " logged: " + line);
    }
    if (total > static_cast<int>(errors.size())) {
      info.notes.push_back("the " + child->name() + " logged " + std::to_string(total) + " errors in all; see " +
                           child->log_path());
    }
  }
  if (!failure.empty()) {
    std::fprintf(stderr, "stitch run: %s\n", failure.c_str());
    info.notes.push_back("the run failed: " + failure);
    exit_code = 1;
  }
  // The ground's per-frame trajectory (the merger's, from the pose stream, written during the flight)
  // stays beside the one the run ends with, which re-composes frames.tsv with the mapper's final
  // keyframes (every frame, culled keyframes included).
  if (fs::exists(fs::path(out) / "trajectory.tum")) {
    std::error_code ignored;
    fs::rename(fs::path(out) / "trajectory.tum", fs::path(out) / "trajectory_ground.tum", ignored);
  }
  try {
    const Evaluation evaluation = FinishRunOutputs(out, &info);
    SaveRunInfo(info, out);
    std::printf("%s in %.1f s\n%s", info.interrupted ? "interrupted" : (exit_code ? "failed" : "done"),
                info.wall_seconds, Summarize(evaluation).c_str());
    if (!info.peak_rss_mb.empty()) {
      std::string peaks;
      for (const auto& [service, mb] : info.peak_rss_mb) {
        peaks +=
            (peaks.empty() ? "" : ", ") + service + " " + std::to_string(static_cast<int>(std::lround(mb))) + " MB";
      }
      std::printf("  peak memory       %s (memory.tsv: every 2 s)\n", peaks.c_str());
    }
    for (const auto& figures : info.link_figures) std::printf("%s\n", figures.c_str());
    for (const auto& note : info.notes) std::printf("note: %s\n", note.c_str());
    std::printf("outputs: %s/{trajectory.tum, map.ply, report.json, trajectory.png, logs/}\n", out.c_str());
    outcome.evaluation = evaluation;
    if (viewer && !viewer->Poll() && !stop.load()) {
      std::printf("viewer: %s shows the finished flight; Ctrl-C ends it\n", viewer_url.c_str());
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
  args.AddOption("--dataset", &a.dataset, "PATH", "TUM RGB-D / EuRoC / KITTI folder, image folder or video (detected)");
  args.AddOption("--live", &a.live, "URI",
                 "a live camera instead: V4L2 device, GStreamer pipeline or stream URL (with --calib; runs until the "
                 "stream ends, --max-frames or Ctrl-C)");
  args.AddOption("--out", &a.out, "DIR", "output folder, new or empty (default: a new folder under runs/)");
  args.AddOption("--failures", &a.failures, "SPEC",
                 "induced failures: none, FRAME:LENGTH,... or default (synthetic: 3 gusts; datasets: none)");
  args.AddOption("--on-loss", &a.on_loss, "MODE", "submap (stitch, default) or relocalize (ORB-SLAM2-like baseline)");
  args.AddOption("--config", &a.config_path, "FILE", "YAML settings (print the defaults with `stitch config`)");
  args.AddOption("--set", &a.settings, "KEY=VALUE",
                 "a setting over the file, e.g. tracker.tracking.orb.num_features=1500");
  args.AddOption("--calib", &a.calibration, "FILE",
                 "calibration overriding the dataset's own (required with --live); an ORB-SLAM2/3 settings file's "
                 "ORBextractor.* also set tracker.tracking.orb (under --set)");
  args.AddOption("--max-frames", &a.max_frames, "N", "play at most N frames");
  args.AddOption("--start-frame", &a.start_frame, "N", "skip the first N frames of the sequence");
  args.AddOption("--vocabulary", &a.vocabulary, "FILE",
                 "bag-of-words vocabulary (a stitch vocabulary, or DBoW2 text such as ORB-SLAM's ORBvoc.txt; "
                 "default: the one shipped)");
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
      "the mapper's keyframes.tsv and submaps.ply, logs/ (one per service); with --journal,\n"
      "merger/submap_updates.lcmlog.");
  if (!args.Parse(argc, argv)) return args.exit_code();

  if (!a.link && !a.netns && (a.link_loss >= 0 || a.link_delay_ms >= 0 || a.link_budget >= 0)) {
    std::fprintf(stderr, "stitch run: --link-loss, --link-delay-ms and --link-budget need --link\n");
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
