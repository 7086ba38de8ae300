#pragma once
// `stitch run`, resolved before anything starts: its flags become settings over the config file,
// the source is summarized, the buses chosen, and every service process gets its name, program,
// arguments and side of the link, in the order they start (the ground's first, ingest last).
// No process is started here; PrepareRunFolder writes what the services read.

#include <string>
#include <vector>

#include "stitch/config/stitch_config.h"
#include "stitch/records/run_info.h"
#include "stitch/source/source.h"

namespace stitch {

// The flags of `stitch run`.
struct RunArgs {
  SourceSpec source;  // --dataset --live --calib --failures --max-frames --start-frame
  std::string out;
  std::string on_loss;
  std::string config_path;
  std::string lcm_url;
  std::string pacing;
  std::string agent = "uav0";
  std::string log_level = "info";
  std::string vocabulary;      // over the settings' vocabulary
  std::string map;             // a saved map the flight is merged into (merger.prior_map)
  bool localize_only = false;  // with `map`: track in it only (tracker.tracking.localize_only)
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

// One service process: its log is OUT/logs/<name>.log.
struct PlannedService {
  std::string name;     // ingest, tracker, mapper, merger, link-aircraft, link-ground, viewer
  std::string program;  // stitch-ingest, ... (beside the launcher)
  std::vector<std::string> args;
  bool on_ground = false;  // runs on the ground's side (its network namespace with --netns)
  // Scheduling niceness: on one machine, with frames at the camera's rate, the ground station's
  // merger and viewer yield the CPU to the aircraft's services, which must keep up with the
  // camera (kGroundNiceness; 0 in lockstep).
  int niceness = 0;
};
constexpr int kGroundNiceness = 10;

struct LaunchPlan {
  std::string out;
  StitchConfig config;
  SourceSpec spec;
  SourceSummary source;
  RunInfo info;                          // run.json as the run starts
  std::string url;                       // the aircraft's bus
  std::string ground_url;                // the ground's (the aircraft's without a link)
  bool linked = false;                   // a link bridge pair between them
  bool netns = false;                    // the two sides in two network namespaces
  std::string link_key;                  // a key made for this run, written by PrepareRunFolder ("" when none)
  std::string viewer_url;                // "" without a viewer; without its token (ViewerAddress)
  std::string viewer_token;              // an access token made for this run's viewer ("" when none)
  std::vector<PlannedService> services;  // in the order they start
};

// Throws stitch::Error for flags, settings or a source no run can take.
LaunchPlan PlanRun(const RunArgs& args, const std::string& out);

// Creates the run folder (never over another run's: the tracker appends to frames.tsv) with its
// logs/, and writes config.yaml, groundtruth.tum (when known), run.json, the run's link key and
// its viewer's access token. Throws stitch::Error.
void PrepareRunFolder(const LaunchPlan& plan);

// The viewer page's address with its access token (read from its file: call it after
// PrepareRunFolder); "" without a viewer.
std::string ViewerAddress(const LaunchPlan& plan);

// How long a service may take to stop after SIGTERM: each drains its queue and writes its files.
// The mapper waits for its link bridge to catch up and for the merger's last requests, a bridge
// sends what waits for up to link.max_queue_s, the merger refines the last closed submap's map and
// then once more at the end (a minute or more each on a 20 km survey).
double StopGraceSeconds(const LaunchPlan& plan, const std::string& service_name);

}  // namespace stitch
