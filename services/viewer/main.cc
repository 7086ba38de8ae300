// stitch-viewer: the ground's live view of the flight, a web page served by this machine.

#include <cstdio>
#include <thread>

#include "services/common/bus.h"
#include "services/common/service.h"
#include "services/config/stitch_config.h"
#include "services/viewer/viewer_service.h"

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
  try {
    common.Apply("viewer");
    std::vector<std::string> settings = common.settings;
    if (!port.empty()) settings.push_back("viewer.port=" + port);
    if (!bind.empty()) settings.push_back(TextSetting("viewer.bind_address", bind));
    const StitchConfig config = LoadStitchConfig(common.config_path, settings);
    const auto& stop = InstallStopSignals();
    auto lcm = bus::OpenLcm(common.lcm_url);
    bus::Publisher publisher(lcm.get(), common.agent);
    ViewerService viewer(lcm.get(), &publisher, config.viewer, bus::SplitAgents(agents_list));
    bus::Dispatcher dispatcher(lcm.get());
    dispatcher.Start();
    viewer.Start();
    STITCH_LOG(INFO) << "serving " << viewer.url() << " (listening on " << common.lcm_url << ")";
    while (!stop.load()) std::this_thread::sleep_for(std::chrono::milliseconds(50));
    dispatcher.Stop();
    viewer.Stop();
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch-viewer: %s\n", e.what());
    return 1;
  }
}
