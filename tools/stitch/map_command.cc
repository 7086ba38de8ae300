// stitch map: rebuilds a merged map from recorded submap updates, without a bus or a flight.

#include <cstdio>
#include <filesystem>
#include <set>

#include "services/common/bus.h"
#include "services/common/convert.h"
#include "services/common/map_convert.h"
#include "services/common/update_journal.h"
#include "stitch/config/stitch_config.h"
#include "stitch/map/map_file.h"
#include "stitch/merging/merge_session.h"
#include "stitch/util/args.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "stitch/util/text_file.h"
#include "stitch/util/time.h"
#include "tools/stitch/commands.h"

namespace fs = std::filesystem;

namespace stitch {

namespace {

// stitch map save RUN --out FILE: the run's map.stitchmap, checked, to a file of the user's.
int MapSave(int argc, char** argv) {
  std::vector<std::string> runs;
  std::string out;
  ArgParser args(
      "stitch map save",
      "Saves a run's largest merged map for a later flight (`stitch run --map FILE`): the map.stitchmap the "
      "merger wrote at the end of the run (docs/map-file.md), read and checked whole, then written to --out. "
      "A run whose merger kept its journal but wrote no map (an older run) can be rebuilt first with "
      "`stitch map RUN/merger/submap_updates.lcmlog --out DIR`.");
  args.AddPositional(&runs, "RUN", "a folder written by `stitch run` (or by `stitch map`)");
  args.AddOption("--out", &out, "FILE", "the saved map to write (e.g. site.stitchmap)");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    if (runs.size() != 1) throw Error("give one run folder (see --help)");
    if (out.empty()) throw Error("give --out FILE");
    const std::string source = (fs::path(runs[0]) / "map.stitchmap").string();
    if (!fs::exists(source)) {
      throw Error(runs[0] +
                  " holds no map.stitchmap (merger.save_map was off, or the run is older); with its "
                  "journal, `stitch map RUN/merger/submap_updates.lcmlog --out DIR` makes one");
    }
    const Stopwatch clock;
    const SavedMap saved = ReadMapFile(source, MakeSubmapId(kSavedMapAgent, 0));
    const double read_s = clock.ElapsedSeconds();
    WriteMapFile(out, saved);
    std::printf("%s: %zu keyframes, %zu points (read and checked in %.2f s); %s\n", out.c_str(),
                saved.map.num_keyframes(), saved.map.num_points(), read_s, saved.description.c_str());
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch map save: %s\n", e.what());
    return 1;
  }
}

// stitch map info FILE: what a saved map holds, and whether it reads.
int MapInfo(int argc, char** argv) {
  std::vector<std::string> files;
  ArgParser args("stitch map info",
                 "Reads a saved map (.stitchmap) whole and says what it holds: format version, size, checksum, "
                 "cameras, keyframes, points, and how long it took to read. Exit status 1 when it is damaged, cut "
                 "short, of another version or not a map, saying which.");
  args.AddPositional(&files, "FILE", "a saved map");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    if (files.size() != 1) throw Error("give one saved map (see --help)");
    const Stopwatch clock;
    const std::string bytes = ReadFileBytes(files[0]);
    const SavedMap saved = DecodeMapFile(bytes, MakeSubmapId(kSavedMapAgent, 0));
    const double read_s = clock.ElapsedSeconds();
    const MapFileSummary s = SummarizeMapFile(bytes, saved);
    std::printf(
        "%s\n  format version %u, %llu bytes, BLAKE2b-256 %s\n  %d camera%s, %d keyframes, %d points, %lld "
        "observations\n  read and checked in %.3f s\n  %s\n",
        files[0].c_str(), s.version, static_cast<unsigned long long>(s.bytes), s.checksum.c_str(), s.cameras,
        s.cameras == 1 ? "" : "s", s.keyframes, s.points, static_cast<long long>(s.observations), read_s,
        s.description.c_str());
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch map info: %s: %s\n", files.empty() ? "" : files[0].c_str(), e.what());
    return 1;
  }
}

}  // namespace

int MapCommand(int argc, char** argv) {
  if (argc > 1 && std::string(argv[1]) == "save") return MapSave(argc - 1, argv + 1);
  if (argc > 1 && std::string(argv[1]) == "info") return MapInfo(argc - 1, argv + 1);
  std::vector<std::string> logs;
  std::string out, config_path, agents = "uav0";
  std::vector<std::string> settings;
  ArgParser args(
      "stitch map",
      "Rebuilds the merged map from recorded submap updates: the merger's journal "
      "(RUN/merger/submap_updates.lcmlog, kept by `stitch run --journal` and by `stitch-merger --state`) or an "
      "lcm-logger recording that holds <agent>/SUBMAP. Runs the merger over them as they were received and "
      "writes its outputs to --out: map.ply, submaps.tsv, keyframes_merged.tsv, connections.tsv, graph.dot, "
      "graph.png, merge_log.tsv, retrieval.tsv, map.stitchmap. `stitch map save RUN --out FILE` saves a run's "
      "map for `stitch run --map`; `stitch map info FILE` says what a saved map holds. A damaged log is read around "
      "its damage (every intact record), "
      "with a warning and exit status 3.");
  args.AddPositional(&logs, "LOG", "an LCM log with submap updates");
  args.AddOption("--out", &out, "DIR", "where to write the merged map (created; must not hold one already)");
  args.AddOption("--config", &config_path, "FILE",
                 "YAML settings (default: built-in; a run's config.yaml reproduces it)");
  args.AddOption("--set", &settings, "KEY=VALUE", "a setting over the file, e.g. merger.min_connection_strength=15");
  args.AddOption("--agents", &agents, "A,B,...", "whose updates to take (channels <agent>/SUBMAP)");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    if (logs.size() != 1) throw Error("give one LCM log (see --help)");
    if (out.empty()) throw Error("give --out DIR");
    if (!fs::exists(logs[0])) throw Error(logs[0] + ": no such file");
    if (fs::exists(fs::path(out) / "submaps.tsv")) throw Error(out + " already holds a merged map; give a new folder");
    const std::vector<std::string> agent_list = bus::SplitAgents(agents);
    if (agent_list.empty()) throw Error("--agents: name at least one aircraft");
    const StitchConfig config = LoadStitchConfig(config_path, settings);
    const Vocabulary vocabulary = LoadVocabulary(config);
    // The merger's session without a bus: each update as it was received, one refinement at the end.
    const ScalePyramid pyramid = ScalePyramid::From(config.tracker.tracking.orb);
    MergeSession session(config.merger, &vocabulary, pyramid, out, agent_list);
    std::set<std::string> channels;
    for (const std::string& agent : agent_list) channels.insert(bus::Channel(agent, bus::kSubmap));
    const Stopwatch clock;
    int64_t refused = 0;
    const SubmapUpdateLogRead read = ReadSubmapUpdateLog(
        logs[0], channels,
        [&](const stitch::submap_update_t& message) {
          try {
            const SubmapUpdate update = FromMessage(message, pyramid);
            if (session.Apply(update, message.header.agent, message.part == 0).accepted) return;
          } catch (const Error& e) {
            STITCH_LOG(WARNING) << "rejected a submap update: " << e.what();
          }
          ++refused;
        },
        [&](const stitch::gnss_fix_t& message) {
          std::string why;
          try {
            if (session.AddGnssFix(message.header.agent, FromMessage(message), &why)) return;
          } catch (const Error& e) {
            why = e.what();
          }
          STITCH_LOG(WARNING) << "refused a GNSS fix: " << why;
          ++refused;
        });
    if (read.updates == 0) throw Error(logs[0] + ": no submap update of " + agents);
    session.Finish();
    if (refused > 0)
      std::fprintf(stderr, "stitch map: %lld submap updates refused (the log says why)\n",
                   static_cast<long long>(refused));
    std::printf("merged %lld submap updates from %s in %.1f s; outputs in %s\n", static_cast<long long>(read.updates),
                logs[0].c_str(), clock.ElapsedMs() / 1000.0, out.c_str());
    if (read.lost_anything()) {
      // The map is made of what was intact; say what it lacks and fail, so no script takes it as whole.
      std::fprintf(stderr,
                   "stitch map: warning: %s is damaged: %zu damaged stretches (%lld bytes, the first at offset %lld; "
                   "%lld of them records whose checksum does not match) and %lld records that do not decode were "
                   "stepped over; the map lacks what they held\n",
                   logs[0].c_str(), read.damage.size(), static_cast<long long>(DamagedBytes(read.damage)),
                   static_cast<long long>(read.damage.empty() ? -1 : read.damage.front().offset),
                   static_cast<long long>(read.checksum_mismatches), static_cast<long long>(read.undecodable));
      return 3;
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch map: %s\n", e.what());
    return 1;
  }
}

}  // namespace stitch
