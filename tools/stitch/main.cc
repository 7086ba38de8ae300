// stitch: the launcher. `stitch run` runs the whole system; other commands evaluate, render,
// and start single services.

#include <unistd.h>
#include <cstdio>
#include <cstring>
#include <string>

#include "stitch/util/child_process.h"
#include "tools/stitch/commands.h"

namespace {

constexpr char kUsage[] =
    "usage: stitch COMMAND [options]   (stitch COMMAND --help for each)\n"
    "\n"
    "stitch is monocular visual SLAM for UAV and handheld video that keeps mapping when tracking\n"
    "fails and stitches the pieces back into one map.\n"
    "\n"
    "commands:\n"
    "  run       run the system on a sequence (default: the synthetic UAV flight with 3 gusts)\n"
    "  eval      evaluate a run folder or a TUM trajectory against ground truth\n"
    "  render    write the synthetic flight as an image folder with ground truth\n"
    "  config    print every setting with its default and meaning\n"
    "  vocab     train a bag-of-words vocabulary, or describe one\n"
    "  bench     time tracking and mapping on a sequence (no bus); --quality: the quality gate\n"
    "  campaign  many randomized flights, each merge scored against ground truth\n"
    "  export    a run's merged map for other tools: colmap (a sparse model on the flight's images)\n"
    "  mosaic    a run's orthomosaic as a GeoTIFF (north up in UTM where the run is on Earth)\n"
    "  map       rebuild the merged map from recorded submap updates (a merger's journal or an LCM log);\n"
    "            map save / map info: a run's map saved for a later flight's --map\n"
    "  record    record a flight's features (what crosses to the ground) with lcm-logger\n"
    "  spy       lcm-spy with stitch's message types, or decode a recorded log with them\n"
    "  ingest    run the ingest service alone (same as stitch-ingest)\n"
    "  tracker   run the tracker service alone (same as stitch-tracker)\n"
    "  mapper    run the mapper service alone (same as stitch-mapper)\n"
    "  merger    run the merger service alone (same as stitch-merger)\n"
    "  link      bridge chosen channels to the other side of a radio link (same as stitch-link)\n"
    "  version   print the version\n";

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2 || !std::strcmp(argv[1], "--help") || !std::strcmp(argv[1], "-h") || !std::strcmp(argv[1], "help")) {
    std::fputs(kUsage, argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  const std::string command = argv[1];
  // Subcommands see their own name as argv[0].
  std::string program = "stitch " + command;
  argv[1] = program.data();
  if (command == "run") return stitch::RunCommand(argc - 1, argv + 1);
  if (command == "eval") return stitch::EvalCommand(argc - 1, argv + 1);
  if (command == "render") return stitch::RenderCommand(argc - 1, argv + 1);
  if (command == "config") return stitch::ConfigCommand(argc - 1, argv + 1);
  if (command == "vocab") return stitch::VocabCommand(argc - 1, argv + 1);
  if (command == "bench") return stitch::BenchCommand(argc - 1, argv + 1);
  if (command == "map") return stitch::MapCommand(argc - 1, argv + 1);
  if (command == "record") return stitch::RecordCommand(argc - 1, argv + 1);
  if (command == "campaign") return stitch::CampaignCommand(argc - 1, argv + 1);
  if (command == "spy") return stitch::SpyCommand(argc - 1, argv + 1);
  if (command == "export") return stitch::ExportCommand(argc - 1, argv + 1);
  if (command == "mosaic") return stitch::MosaicCommand(argc - 1, argv + 1);
  if (command == "version" || command == "--version") {
    std::printf("stitch %s\n", STITCH_VERSION);
    return 0;
  }
  if (command == "ingest" || command == "tracker" || command == "mapper" || command == "merger" || command == "link") {
    const std::string service = stitch::ExecutableDir() + "/stitch-" + command;
    argv[1] = const_cast<char*>(service.c_str());
    execv(service.c_str(), argv + 1);
    std::fprintf(stderr, "stitch: cannot start %s: %s\n", service.c_str(), std::strerror(errno));
    return 127;
  }
  std::fprintf(stderr, "stitch: unknown command '%s'\n\n%s", command.c_str(), kUsage);
  return 2;
}
