// stitch-merger: joins the submaps on <agent>/SUBMAP into one map (ground station).

#include "services/common/service_main.h"
#include "services/merger/merger_service.h"
#include "stitch/util/time.h"

int main(int argc, char** argv) {
  using namespace stitch;
  ServiceCommandLine common;
  std::string record_dir, state_dir, agents_list;
  ArgParser args("stitch-merger",
                 "Receives submap updates on <agent>/SUBMAP, finds connected frames between submaps, builds the submap "
                 "graph and merges along its strongest connections; publishes <agent>/GLOBAL_MAP. Runs until SIGINT "
                 "or SIGTERM.");
  common.Register(&args);
  args.AddOption(
      "--record", &record_dir, "DIR",
      "write map.ply, submaps.tsv, keyframes_merged.tsv, graph.dot, graph.png, merge_log.tsv and retrieval.tsv to DIR");
  args.AddOption("--state", &state_dir, "DIR",
                 "keep the merger's store in DIR (submap_updates.lcmlog, appended as updates arrive); a merger "
                 "restarted with the same DIR resumes where the last one stopped or was killed");
  args.AddOption("--agents", &agents_list, "A,B,...",
                 "merge the submaps of these aircraft (their <agent>/SUBMAP), e.g. uav0,uav1 (default: --agent); each "
                 "aircraft needs its own tracker.tracking.agent_number");
  if (!args.Parse(argc, argv)) return args.exit_code();
  return RunService("merger", common, common.settings, [&](ServiceProcess& process) {
    const Vocabulary vocabulary = LoadVocabulary(process.config);
    MergerService merger(process.lcm, process.publisher, process.config.merger, process.config.tracker.tracking.orb,
                         &vocabulary, record_dir, state_dir, bus::SplitAgents(agents_list));
    // The mappers send their final submap states as they stop: keep listening until the bus has
    // been quiet for half a second (at most 5 s).
    const auto until_quiet = [&] {
      const double deadline = MonotonicSeconds() + 5.0;
      while (MonotonicSeconds() < deadline && MonotonicSeconds() - merger.last_receive_time() < 0.5) {
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
      }
    };
    process.RunUntilStopped(merger, ServiceProcess::StopOrder::kBusFirst, until_quiet);
    STITCH_LOG(INFO) << "stopped after " << merger.updates_received() << " submap updates";
    return 0;
  });
}
