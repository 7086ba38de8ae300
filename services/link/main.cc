// stitch-link: carries chosen LCM channels to the other side of a radio link over plain UDP.

#include <cstdio>
#include <string>
#include <thread>
#include <vector>

#include "services/common/service_main.h"
#include "services/link/link_auth.h"
#include "services/link/link_bridge.h"
#include "stitch/util/error.h"
#include "stitch/util/options.h"

namespace {

// `stitch-link keygen FILE`: the key both bridges of a pair share.
int KeygenCommand(int argc, char** argv) {
  using namespace stitch;
  std::vector<std::string> paths;
  ArgParser args("stitch-link keygen",
                 "Writes a new random key for one aircraft-ground pair of link bridges to FILE (mode 0600; an "
                 "existing file is never overwritten). Copy it to both sides over a channel you trust (not the "
                 "radio) and give it to both bridges as link.key_file.");
  args.AddPositional(&paths, "FILE", "where to write the key");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    if (paths.size() != 1) throw Error("give one FILE (see --help)");
    link::GenerateKeyFile(paths[0]);
    std::printf("wrote a link key to %s (mode 0600): give it to both bridges as link.key_file\n", paths[0].c_str());
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch-link keygen: %s\n", e.what());
    return 1;
  }
}

}  // namespace

int main(int argc, char** argv) {
  using namespace stitch;
  if (argc >= 2 && std::string(argv[1]) == "keygen") return KeygenCommand(argc - 1, argv + 1);
  ServiceCommandLine common;
  LinkOptions given;
  ArgParser args("stitch-link",
                 "Link bridge: sends the LCM channels matching --forward to the bridge at --peer over UDP and "
                 "publishes what that bridge sends on this side's bus. Lost datagrams are asked for again; a "
                 "budget paces what is sent. Run one on each side of the link. Runs until SIGINT or SIGTERM.");
  common.Register(&args);
  args.AddOption("--forward", &given.forward, "REGEX", "channels to send to the other side (overrides link.forward)");
  args.AddOption("--accept", &given.accept, "REGEX",
                 "channels published from the other side: its --forward (overrides link.accept)");
  args.AddOption("--listen", &given.listen, "ADDR:PORT", "UDP address to receive on (overrides link.listen)");
  args.AddOption("--peer", &given.peer, "ADDR:PORT", "the other side's bridge (overrides link.peer)");
  args.AddOption("--budget", &given.budget_bytes_per_s, "BYTES/S",
                 "bandwidth budget, 0 for none (overrides link.budget_bytes_per_s)");
  args.AddOption("--key", &given.key_file, "FILE",
                 "key both bridges share, from `stitch-link keygen FILE` (overrides link.key_file)");
  args.AddFlag("--insecure", &given.insecure, "run without a key: datagrams unauthenticated (overrides link.insecure)");
  args.AddOption("--side", &given.side, "aircraft|ground",
                 "which bridge of the pair this is: each direction has its own key (overrides link.side)");
  args.AddOption("--loss", &given.loss, "P", "inject: drop each datagram sent with probability P (tests, rehearsals)");
  args.AddOption("--delay-ms", &given.delay_ms, "MS", "inject: delay every datagram sent by MS");
  args.AddOption("--jitter-ms", &given.jitter_ms, "MS", "inject: extra uniform delay up to MS (reorders)");
  args.AddOption("--seed", &given.seed, "N", "seed of the injected loss and jitter");
  args.AddEpilog(
      "Example, the aircraft (10.0.0.2) and the ground station (10.0.0.1), with a key made once by\n"
      "`stitch-link keygen uav0.key` and copied to both:\n"
      "  aircraft$ stitch-link --side aircraft --forward "
      "'uav0/(SUBMAP|SEQUENCE|TRACKING_STATUS|POSE|GNSS|SERVICE|LINK_STATUS|KEYFRAME_IMAGE)' "
      "--key uav0.key \\\n"
      "              --accept 'uav0/SUBMAP_REQUEST' --listen 0.0.0.0:7720 --peer 10.0.0.1:7721 --budget 250000\n"
      "  ground$   stitch-link --side ground --forward 'uav0/SUBMAP_REQUEST' --key uav0.key --listen 0.0.0.0:7721 \\\n"
      "              --accept 'uav0/(SUBMAP|SEQUENCE|TRACKING_STATUS|POSE|GNSS|SERVICE|LINK_STATUS|KEYFRAME_IMAGE)' "
      "--peer "
      "10.0.0.2:7720\n"
      "Every 10 s the log says what was sent, repaired and received.\n");
  if (!args.Parse(argc, argv)) return args.exit_code();
  std::vector<std::string> settings = common.settings;
  if (args.Given("--forward")) settings.push_back(TextSetting("link.forward", given.forward));
  if (args.Given("--accept")) settings.push_back(TextSetting("link.accept", given.accept));
  if (args.Given("--listen")) settings.push_back(TextSetting("link.listen", given.listen));
  if (args.Given("--peer")) settings.push_back(TextSetting("link.peer", given.peer));
  if (args.Given("--budget")) settings.push_back(NumberSetting("link.budget_bytes_per_s", given.budget_bytes_per_s));
  if (args.Given("--key")) settings.push_back(TextSetting("link.key_file", given.key_file));
  if (given.insecure) settings.push_back("link.insecure=true");
  if (args.Given("--side")) settings.push_back(TextSetting("link.side", given.side));
  if (args.Given("--loss")) settings.push_back(NumberSetting("link.loss", given.loss));
  if (args.Given("--delay-ms")) settings.push_back(NumberSetting("link.delay_ms", given.delay_ms));
  if (args.Given("--jitter-ms")) settings.push_back(NumberSetting("link.jitter_ms", given.jitter_ms));
  if (args.Given("--seed")) settings.push_back("link.seed=" + std::to_string(given.seed));
  return RunService("link", common, settings, [&](ServiceProcess& process) {
    const LinkOptions& options = process.config.link;
    LinkBridge bridge(process.lcm, options, process.publisher->authenticator());
    bus::Dispatcher dispatcher(process.lcm);
    dispatcher.Start();
    bridge.Start();
    STITCH_LOG(INFO) << "bridging " << common.lcm_url;
    // Once a second, the figures on this side's <agent>/LINK_STATUS.
    const std::string status_channel = bus::Channel(common.agent, bus::kLinkStatus);
    double last_status = MonotonicSeconds();
    int64_t last_bytes = 0;
    while (!process.stop.load()) {
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
      const double now = MonotonicSeconds();
      if (now - last_status < 1.0) continue;
      const int64_t bytes = bridge.counts().bytes_sent;
      stitch::link_status_t status = bridge.Status((bytes - last_bytes) / (now - last_status));
      process.publisher->Publish(status_channel, &status);
      last_status = now;
      last_bytes = bytes;
    }
    // What is still queued (a submap's final state sent as the aircraft lands) goes out first,
    // and its lost datagrams are repaired: until the other side has been quiet for a second, at
    // most as long as a message may wait (max_queue_s) and 5 s more.
    const double deadline = MonotonicSeconds() + options.max_queue_s + 5.0;
    if (!bridge.Settled(1.0)) {
      STITCH_LOG(INFO) << "sending what waits before stopping: " << bridge.Describe();
    }
    while (!bridge.Settled(1.0) && MonotonicSeconds() < deadline) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    dispatcher.Stop();
    bridge.Stop();
    STITCH_LOG(INFO) << "stopped: " << bridge.Describe();
    return 0;
  });
}
