// stitch record: lcm-logger on the channels that cross from the aircraft to the ground.

#include <unistd.h>

#include <cstdio>
#include <filesystem>

#include "services/common/bus.h"
#include "stitch/util/args.h"
#include "stitch/util/error.h"
#include "tools/stitch/commands.h"

namespace stitch {

int RecordCommand(int argc, char** argv) {
  std::vector<std::string> files;
  std::string lcm_url = bus::DefaultLcmUrl(), agents = "uav0";
  bool all = false, force = false;
  ArgParser args(
      "stitch record",
      "Records a flight's features with lcm-logger until Ctrl-C: for each aircraft its submap updates and "
      "requests, tracking and service statuses, its pose stream, sequence information, the global map and the "
      "map cloud (never images, unless --all). `stitch map FILE` rebuilds the merged map from the "
      "recording; lcm-logplayer replays it onto a bus, where stitch-viewer shows it as it was flown.");
  args.AddPositional(&files, "FILE", "the LCM log to write");
  args.AddOption("--lcm-url", &lcm_url, "URL", "the bus to record");
  args.AddOption("--agents", &agents, "A,B,...", "the aircraft whose channels to record");
  args.AddFlag("--all", &all, "every channel of those aircraft, frames included");
  args.AddFlag("--force", &force, "overwrite FILE");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    if (files.size() != 1) throw Error("give one FILE to write (see --help)");
    if (std::filesystem::exists(files[0]) && !force) throw Error(files[0] + " exists; give --force to overwrite it");
    std::string names;
    for (const std::string& agent : bus::SplitAgents(agents)) names += (names.empty() ? "" : "|") + agent;
    if (names.empty()) throw Error("--agents: name at least one aircraft");
    const std::string channels =
        "(" + names + ")/" +
        (all ? std::string(".*")
             : "(SUBMAP|SUBMAP_REQUEST|TRACKING_STATUS|POSE|SERVICE|SEQUENCE|GLOBAL_MAP|MAP_CLOUD)");
    std::vector<std::string> command = {"lcm-logger", "--lcm-url=" + bus::WithReceiveBuffer(lcm_url),
                                        "--channel=" + channels, "-f", files[0]};
    std::vector<char*> argv_out;
    for (std::string& s : command) argv_out.push_back(s.data());
    argv_out.push_back(nullptr);
    std::fprintf(stderr, "stitch record: %s -> %s (Ctrl-C to stop)\n", channels.c_str(), files[0].c_str());
    execvp("lcm-logger", argv_out.data());
    throw Error("cannot run lcm-logger (Debian package liblcm-bin)");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch record: %s\n", e.what());
    return 1;
  }
}

}  // namespace stitch
