#pragma once
// The service processes of one `stitch run`: started in the plan's order, each on its side of the
// link (its network namespace with --netns), watched while the flight plays, and stopped upstream
// first with each service's grace, so each drains its queue and writes its files.

#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "stitch/util/child_process.h"
#include "tools/stitch/launch/launch_plan.h"
#include "tools/stitch/launch/split_network.h"

namespace stitch {

class RunServices {
 public:
  // `network` (null without --netns) must outlive this.
  RunServices(const LaunchPlan& plan, const SplitNetwork* network);

  // Starts every planned service; throws stitch::Error when one cannot be started. The calling
  // thread ends on the aircraft's side.
  void StartAll();
  // Null when not planned (or not started).
  ChildProcess* Find(const std::string& name) const;
  // Why the run must stop: a service other than ingest ended, or ingest failed ("" if none).
  // The viewer is a window on the flight, never a reason to stop it: one that ended is started
  // again (at most kViewerRestarts times), said on stderr and in the run's notes.
  std::string Failure();
  // Whether ingest has played everything (and ended well).
  bool IngestDone();
  // Each service's resident memory, one line each, to memory.tsv (seconds, the tracker's frame).
  void SampleMemory(double seconds, int frame);
  // Stops every service, upstream first (SIGTERM, each its grace: StopGraceSeconds); the viewer
  // stays up when `keep_viewer` (it shows the finished flight). Returns why a stop went wrong
  // ("" if none) unless `quiet_statuses` (an interrupted or failed run).
  std::string StopAll(bool keep_viewer, bool quiet_statuses);
  // What the services leave for run.json: each one's peak memory, each bridge's last word, and
  // the errors each logged (also printed).
  void Report(RunInfo* info) const;

  static constexpr int kViewerRestarts = 5;

 private:
  // Starts `service`, its log under logs/ as `log_name`.log.
  std::unique_ptr<ChildProcess> Start(const PlannedService& service, const std::string& log_name) const;
  // The viewer ended: started again while restarts are left.
  void RestartViewer(std::unique_ptr<ChildProcess>* viewer);

  const LaunchPlan& plan_;
  const SplitNetwork* network_;
  std::vector<std::unique_ptr<ChildProcess>> children_;
  std::vector<std::unique_ptr<ChildProcess>> ended_viewers_;  // kept for their CPU and memory
  std::vector<std::string> viewer_notes_;
  std::unique_ptr<std::ofstream> memory_samples_;
};

// The summary `stitch run` prints at the end (figures, peak memory, the bridges' and notes).
void PrintRunSummary(const RunInfo& info, const std::string& evaluation_summary, const std::string& out, int exit_code);

}  // namespace stitch
