// stitch-viewer: the ground's live view of the flight, a web page served by this machine.

#include "services/common/service_main.h"
#include "services/viewer/viewer_service.h"
#include "stitch/util/options.h"

int main(int argc, char** argv) {
  using namespace stitch;
  ServiceCommandLine common;
  std::string agents_list, port, bind;
  ArgParser args("stitch-viewer",
                 "Serves a web page (http://127.0.0.1:8080/ by default) that shows the flight live: the merged map's "
                 "points, each submap's keyframe trajectory, the camera, the submap graph, tracking and link state and "
                 "the merge log. Listens to the merger's <agent>/GLOBAL_MAP and <agent>/MAP_CLOUD and to each "
                 "aircraft's TRACKING_STATUS, POSE and LINK_STATUS; works the same on an lcm-logplayer replay. Runs "
                 "until SIGINT or SIGTERM. Settings: the viewer section of the config (stitch config).");
  common.Register(&args);
  args.AddOption("--agents", &agents_list, "A,B,...", "show these aircraft (default: --agent)");
  args.AddOption("--port", &port, "PORT", "TCP port of the page (viewer.port, default 8080)");
  args.AddOption("--bind", &bind, "ADDRESS",
                 "address to listen on (viewer.bind_address, default 127.0.0.1: this machine only; the page has no "
                 "login)");
  if (!args.Parse(argc, argv)) return args.exit_code();
  std::vector<std::string> settings = common.settings;
  if (!port.empty()) settings.push_back("viewer.port=" + port);
  if (!bind.empty()) settings.push_back(TextSetting("viewer.bind_address", bind));
  return RunService("viewer", common, settings, [&](ServiceProcess& process) {
    ViewerService viewer(process.lcm, process.publisher, process.config.viewer, bus::SplitAgents(agents_list));
    STITCH_LOG(INFO) << "serving " << viewer.url();
    process.RunUntilStopped(viewer, ServiceProcess::StopOrder::kBusFirst);
    return 0;
  });
}
