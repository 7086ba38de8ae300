#include "tools/stitch/launch/launch_plan.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>

#include "services/common/bus.h"
#include "services/common/secret_file.h"
#include "services/link/link_auth.h"
#include "stitch/io/calibration.h"
#include "stitch/io/output_frames.h"
#include "stitch/map/map_file.h"
#include "stitch/util/error.h"
#include "stitch/util/time.h"
#include "tools/stitch/launch/split_network.h"

namespace fs = std::filesystem;

namespace stitch {

namespace {

std::vector<std::string> With(std::vector<std::string> args, const std::vector<std::string>& more) {
  args.insert(args.end(), more.begin(), more.end());
  return args;
}

// What the launcher writes into run.json about the link between the sides.
std::string DescribeLink(const LinkOptions& link, bool netns) {
  char text[160];
  std::snprintf(
      text, sizeof(text), "loss %g, delay %g ms, jitter %g ms, budget %s%s", link.loss, link.delay_ms, link.jitter_ms,
      link.budget_bytes_per_s > 0 ? (std::to_string(static_cast<int64_t>(link.budget_bytes_per_s)) + " B/s").c_str()
                                  : "none",
      netns ? ", two network namespaces" : ", loopback");
  return std::string(text) +
         (link.insecure && link.key_file.empty() ? ", unauthenticated (insecure)" : ", authenticated");
}

}  // namespace

LaunchPlan PlanRun(const RunArgs& a, const std::string& out) {
  LaunchPlan plan;
  plan.out = out;
  bus::CheckAgentName(a.agent);
  CheckSourceSpec(a.source);
  if (!a.vocabulary.empty() && !fs::is_regular_file(a.vocabulary)) {
    throw Error(a.vocabulary + ": no such vocabulary file (--vocabulary)");
  }
  // The launcher's own flags are settings like --set's, over the file.
  std::vector<std::string> settings = a.settings;
  if (!a.pacing.empty()) settings.push_back(TextSetting("ingest.pacing", a.pacing));
  if (!a.on_loss.empty()) settings.push_back(TextSetting("tracker.on_loss", a.on_loss));
  if (a.link_loss >= 0) settings.push_back(NumberSetting("link.loss", a.link_loss));
  if (a.link_delay_ms >= 0) settings.push_back(NumberSetting("link.delay_ms", a.link_delay_ms));
  if (a.link_budget >= 0) settings.push_back(NumberSetting("link.budget_bytes_per_s", a.link_budget));
  const std::string& calibration = a.source.calibration_path;
  RunInfo& info = plan.info;
  if (!calibration.empty()) {
    for (const std::string& setting : OrbSlamFeatureSettings(calibration)) {
      // A --set of the same key comes later and wins: the note says which value runs.
      const std::string key = setting.substr(0, setting.find('=') + 1);
      const auto over = std::find_if(a.settings.rbegin(), a.settings.rend(),
                                     [&](const std::string& s) { return s.rfind(key, 0) == 0; });
      info.notes.push_back("from the ORB-SLAM settings " + calibration + ": " + setting +
                           (over == a.settings.rend() ? "" : ", overridden by --set " + *over));
    }
  }
  plan.config = LoadStitchConfig(a.config_path, CommandLineSettings(calibration, a.vocabulary, settings));
  if (!a.map.empty()) {
    // Read here first, so a file the merger cannot use stops the run before anything starts.
    const SavedMap saved = ReadMapFile(a.map, MakeSubmapId(kSavedMapAgent, 0));
    plan.config.merger.prior_map = plan.config.tracker.tracking.prior_map = fs::absolute(a.map).string();
    plan.config.tracker.tracking.localize_only = a.localize_only;
    info.notes.push_back("flown in the saved map " + a.map + ": " + std::to_string(saved.map.num_keyframes()) +
                         " keyframes (" + saved.description + ")");
  }
  const StitchConfig& config = plan.config;
  plan.spec = a.source;
  // The config may name a live camera.
  if (plan.spec.live_uri.empty() && plan.spec.dataset_path.empty()) plan.spec.live_uri = config.ingest.live;
  plan.spec.synthetic = config.synthetic;
  plan.spec.max_working_pixels = config.ingest.max_working_pixels;
  plan.spec.video_deblocking = config.ingest.video_deblocking;
  plan.source = SummarizeSource(plan.spec);
  if (plan.source.num_frames == 0) throw Error("the sequence has no frames");
  if (plan.config.tracker.tracking.rolling_shutter_line_us < 0) {
    plan.config.tracker.tracking.rolling_shutter_line_us = SourceLineDelayUs(plan.spec, plan.source.camera);
  }
  // A camera mount the source states levels the maps its GNSS fixes place.
  GeoReferenceOptions& georeference = plan.config.merger.georeference;
  if (georeference.level_by_camera == "auto") {
    const std::string up_axis = SourceCameraUpAxis(plan.spec);
    georeference.level_by_camera = up_axis.empty() ? "false" : "true";
    if (!up_axis.empty() && georeference.camera_up_axis == "auto") georeference.camera_up_axis = up_axis;
  }
  if (!calibration.empty()) {
    if (const std::string doubt = CalibrationDoubts(plan.source.camera); !doubt.empty()) info.notes.push_back(doubt);
  }
  if (!config.vocabulary.empty()) {  // one the user chose: read once here too, so the summary can doubt it
    if (const std::string doubt = VocabularyDoubts(LoadVocabulary(config)); !doubt.empty()) {
      info.notes.push_back(config.vocabulary + ": " + doubt);
    }
  }

  plan.linked = a.link || a.netns;
  plan.netns = a.netns;
  plan.url = a.lcm_url.empty() ? bus::UnusedLocalUdpUrl() : a.lcm_url;
  // With a link, the merger is on a bus of its own, reached only through the bridges.
  plan.ground_url = plan.url;
  if (plan.linked) {
    do plan.ground_url = bus::UnusedLocalUdpUrl();
    while (plan.ground_url == plan.url);
    info.link = DescribeLink(config.link, a.netns);
  }
  // The camera's frames on a bus of their own (bus.frame_url), where the run chose the bus: the
  // other services' sockets never receive them.
  if (a.lcm_url.empty() && plan.config.bus.frame_url.empty()) {
    do plan.config.bus.frame_url = bus::UnusedLocalUdpUrl();
    while (plan.config.bus.frame_url == plan.url || plan.config.bus.frame_url == plan.ground_url);
  }
  info.source = plan.source.description;
  info.dataset = plan.spec.dataset_path;
  info.start_frame = plan.spec.start_frame;
  info.frames_total = plan.source.num_frames;
  info.frames_unusable = plan.source.num_frames < 0 ? 0 : plan.source.failures.CountWithin(plan.source.num_frames);
  info.failures = plan.source.failures.ToString();
  info.on_loss = config.tracker.on_loss;
  info.pacing = plan.spec.live_uri.empty() ? config.ingest.pacing : "live";
  info.lcm_url = plan.url;
  info.agent = a.agent;
  info.started_at = LocalTimestamp("%Y-%m-%dT%H:%M:%S%z");

  // Every service reads the resolved settings the run folder keeps.
  const std::string config_file = (fs::path(out) / "config.yaml").string();
  const auto on_bus = [&](const std::string& bus_url) {
    return std::vector<std::string>{"--lcm-url", bus_url,     "--agent",     a.agent,
                                    "--config",  config_file, "--log-level", a.log_level};
  };
  const std::vector<std::string> aircraft = on_bus(plan.url), ground = on_bus(plan.ground_url);
  std::vector<std::string> merger_args = With(ground, {"--record", out});
  if (a.journal) merger_args = With(merger_args, {"--state", (fs::path(out) / "merger").string()});
  // Frames at the camera's rate: the ground's services yield the CPU to the aircraft's. In
  // lockstep nothing is gained, and the run stays the same run on any machine load.
  const int ground_niceness = plan.info.pacing == "lockstep" ? 0 : kGroundNiceness;
  plan.services.push_back({"merger", "stitch-merger", merger_args, true, ground_niceness});
  if (plan.linked) {
    const std::string air_host = a.netns ? SplitNetwork::kAircraftAddress : "127.0.0.1";
    const std::string ground_host = a.netns ? SplitNetwork::kGroundAddress : "127.0.0.1";
    const std::vector<int> ports = bus::UnusedUdpPorts(2);
    const std::string air_at = air_host + ":" + std::to_string(ports[0]);
    const std::string ground_at = ground_host + ":" + std::to_string(ports[1]);
    const std::string aircraft_sends =
        a.agent + "/(SUBMAP|SEQUENCE|TRACKING_STATUS|POSE|GNSS|SERVICE|LINK_STATUS|KEYFRAME_IMAGE)";
    const std::string ground_sends = a.agent + "/" + bus::kSubmapRequest;
    // Authenticated as deployed: the config's key, else one made for this run (beside its outputs).
    std::vector<std::string> key;
    if (!config.link.key_file.empty()) {
      key = {"--key", config.link.key_file};
    } else if (!config.link.insecure) {
      plan.link_key = (fs::path(out) / "link.key").string();
      key = {"--key", plan.link_key};
    }
    plan.services.push_back({"link-ground", "stitch-link",
                             With(With(ground, {"--side", "ground", "--forward", ground_sends, "--accept",
                                                aircraft_sends, "--listen", ground_at, "--peer", air_at}),
                                  key),
                             true});
    plan.services.push_back({"link-aircraft", "stitch-link",
                             With(With(aircraft, {"--side", "aircraft", "--forward", aircraft_sends, "--accept",
                                                  ground_sends, "--listen", air_at, "--peer", ground_at}),
                                  key),
                             false});
  }
  if (a.viewer) {
    const int port = a.viewer_port >= 0 ? a.viewer_port : config.viewer.port;
    plan.viewer_url = "http://" + config.viewer.bind_address + ":" + std::to_string(port) + "/";
    // Off this machine's loopback the page needs a token: one made for this run (beside its
    // outputs, mode 0600) unless the config names one; the address printed carries it.
    if (!config.viewer.Loopback() && config.viewer.access_token_file.empty()) {
      plan.viewer_token = (fs::path(out) / "viewer.token").string();
      plan.config.viewer.access_token_file = plan.viewer_token;
    }
    plan.services.push_back(
        {"viewer", "stitch-viewer", With(ground, {"--port", std::to_string(port)}), true, ground_niceness});
  }
  plan.services.push_back({"mapper", "stitch-mapper", With(aircraft, {"--record", out}), false});
  plan.services.push_back({"tracker", "stitch-tracker",
                           With(aircraft, {"--record", (fs::path(out) / "frames.tsv").string(), "--state",
                                           (fs::path(out) / "logs" / "tracker.state").string()}),
                           false});
  plan.services.push_back(
      {"ingest", "stitch-ingest",
       With(With(aircraft, SourceArguments(plan.spec)), {"--record", (fs::path(out) / "ingest.json").string()}),
       false});
  return plan;
}

void PrepareRunFolder(const LaunchPlan& plan) {
  const fs::path out(plan.out);
  if (fs::exists(out) && !fs::is_empty(out)) {
    throw Error(plan.out + " exists and is not empty; give --out a new folder (or remove that one)");
  }
  fs::create_directories(out / "logs");
  SaveStitchConfig(plan.config, (out / "config.yaml").string());
  if (!plan.source.ground_truth.empty())
    plan.source.ground_truth.WriteTum((out / "groundtruth.tum").string(), output_frames::kGroundTruth);
  if (!plan.source.gnss.fixes.empty()) WriteGnssCsv((out / "gnss.csv").string(), plan.source.gnss);
  SaveRunInfo(plan.info, plan.out);
  if (!plan.link_key.empty()) link::GenerateKeyFile(plan.link_key);
  if (!plan.viewer_token.empty()) GenerateSecretFile(plan.viewer_token, "viewer access token");
}

std::string ViewerAddress(const LaunchPlan& plan) {
  if (plan.viewer_url.empty() || plan.config.viewer.access_token_file.empty()) return plan.viewer_url;
  return plan.viewer_url + "?token=" +
         SecretHex(
             LoadSecretFile(plan.config.viewer.access_token_file, "viewer access token", "viewer.access_token_file"));
}

double StopGraceSeconds(const LaunchPlan& plan, const std::string& name) {
  const SenderOptions& delivery = plan.config.mapper.delivery;
  if (name == "mapper") return std::max(120.0, delivery.stop_link_drain_s + delivery.stop_linger_s + 60.0);
  if (name.rfind("link", 0) == 0) return std::max(120.0, plan.config.link.max_queue_s + 65.0);
  if (name == "merger") return 600.0;
  return 15.0;
}

}  // namespace stitch
