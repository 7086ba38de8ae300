// stitch-tracker: tracks each frame from <agent>/FRAME and publishes poses and keyframes.

#include "services/common/service_main.h"
#include "services/tracker/tracker_service.h"
#include "stitch/util/options.h"

int main(int argc, char** argv) {
  using namespace stitch;
  ServiceCommandLine common;
  std::string record_path, on_loss, state_file;
  ArgParser args("stitch-tracker",
                 "Tracks the camera in every frame on <agent>/FRAME; publishes <agent>/TRACKING_STATUS per frame "
                 "and acknowledges frames on <agent>/FRAME_ACK. Runs until SIGINT or SIGTERM.");
  common.Register(&args);
  args.AddOption("--record", &record_path, "FILE", "also write one line per frame to FILE (frames.tsv)");
  args.AddOption("--on-loss", &on_loss, "MODE", "submap or relocalize (overrides the config)");
  args.AddOption("--state", &state_file, "FILE",
                 "keep the next submap number in FILE across restarts (overrides the config)");
  if (!args.Parse(argc, argv)) return args.exit_code();
  std::vector<std::string> settings = common.settings;
  if (args.Given("--on-loss")) settings.push_back(TextSetting("tracker.on_loss", on_loss));
  if (args.Given("--state")) settings.push_back(TextSetting("tracker.state_file", state_file));
  return RunService(
      "tracker", common, settings,
      [&](ServiceProcess& process) {
        const Vocabulary vocabulary = LoadVocabulary(process.config);
        TrackerService tracker(process.lcm, process.publisher, process.config.tracker, &vocabulary, record_path,
                               process.frame_lcm);
        process.RunUntilStopped(tracker, ServiceProcess::StopOrder::kBusFirst);
        if (tracker.points_waits() > 0) {
          STITCH_LOG(INFO) << "waited " << tracker.points_waits()
                           << " times for a keyframe's new points on a thin map ("
                           << static_cast<int>(tracker.points_wait_s() * 1000) << " ms in all)";
        }
        STITCH_LOG(INFO) << "stopped after " << tracker.frames_tracked() << " frames";
        return 0;
      },
      FrameBus::kOpen);
}
