#pragma once
// run.json: what a run was (source, failures, policy, pacing, bus, link, timing, notes). Written
// by `stitch run` when it starts and when it ends, read by `stitch eval` to rebuild the outputs.

#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace stitch {

struct RunInfo {
  std::string source;   // what was played
  std::string dataset;  // its path; empty for the synthetic flight
  int start_frame = 0;  // frames of the sequence skipped before the first played
  int frames_total = 0;
  int frames_unusable = 0;
  std::string failures;  // the failure schedule, "none" when empty
  std::string on_loss;
  std::string pacing;
  std::string lcm_url;
  std::string agent;
  std::string link;                       // the link bridges between the sides; "" when one bus
  std::vector<std::string> link_figures;  // each bridge's last word: what it sent, repaired, received
  std::vector<std::string> geo_figures;   // where each map was placed on Earth by the GNSS fixes (geo/)
  std::string started_at;
  double wall_seconds = 0;
  bool interrupted = false;
  std::vector<std::string> notes;  // what the user should know about this run
  // Each service's peak resident memory, MB (the kernel's, once it ended); the samples during the
  // flight are in memory.tsv.
  std::map<std::string, double> peak_rss_mb;
  // Each service's CPU time (user + system), seconds, once it ended: what the run cost.
  std::map<std::string, double> cpu_s;

  nlohmann::json ToJson() const;
  static RunInfo FromJson(const nlohmann::json& json);  // throws stitch::Error on missing keys
};

// Writes RUN_DIR/run.json (as one act). Throws stitch::Error on I/O failure.
void SaveRunInfo(const RunInfo& info, const std::string& run_dir);
RunInfo LoadRunInfo(const std::string& run_dir);

}  // namespace stitch
