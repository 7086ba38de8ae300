#pragma once
// The outputs of a run folder, built from what the services wrote into it:
//   frames.tsv (tracker), poses.tsv and map.ply (when a merger / mapper wrote them),
//   groundtruth.tum and run.json (launcher)
// become trajectory.tum, poses.tsv, map.ply, report.json and trajectory.png. `stitch run` calls
// this at the end; `stitch eval RUN_DIR` calls it again on a finished folder.

#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "stitch/eval/evaluation.h"

namespace stitch {

struct RunInfo {
  std::string source;        // what was played
  std::string dataset;       // its path; empty for the synthetic flight
  int frames_total = 0;
  int frames_unusable = 0;
  std::string failures;      // the failure schedule, "none" when empty
  std::string on_loss;
  std::string pacing;
  std::string lcm_url;
  std::string agent;
  std::string link;                       // the link bridges between the sides; "" when one bus
  std::vector<std::string> link_figures;  // each bridge's last word: what it sent, repaired, received
  std::string started_at;
  double wall_seconds = 0;
  bool interrupted = false;
  std::vector<std::string> notes;  // what the user should know about this run

  nlohmann::json ToJson() const;
  static RunInfo FromJson(const nlohmann::json& json);  // throws stitch::Error on missing keys
};

// Writes run.json. Throws stitch::Error on I/O failure.
void SaveRunInfo(const RunInfo& info, const std::string& run_dir);
RunInfo LoadRunInfo(const std::string& run_dir);

// Builds the outputs listed above; adds to `info.notes` what a reader must know (an empty map, a
// tracker without SLAM core). Returns the evaluation also written to report.json.
Evaluation FinishRunOutputs(const std::string& run_dir, RunInfo* info);

}  // namespace stitch
