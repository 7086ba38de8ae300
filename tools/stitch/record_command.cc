// stitch record: the channels that cross from the aircraft to the ground, written to an LCM log
// (the format lcm-logger writes), and what the recording missed.

#include <lcm/lcm-cpp.hpp>

#include <atomic>
#include <cinttypes>
#include <cstdio>
#include <filesystem>
#include <map>

#include "services/common/bus.h"
#include "services/common/sequence_gaps.h"
#include "services/common/service.h"
#include "stitch/util/args.h"
#include "stitch/util/error.h"
#include "stitch/util/time.h"
#include "tools/stitch/commands.h"

namespace stitch {
namespace {

// Each message as it arrives: into the log, and its header into the count of what was missed.
class Recorder {
 public:
  explicit Recorder(lcm::LogFile* log) : log_(log) {}

  void OnMessage(const lcm::ReceiveBuffer* buffer, const std::string& channel) {
    lcm::LogEvent event{};
    event.timestamp = buffer->recv_utime;
    event.channel = channel;
    event.datalen = static_cast<int32_t>(buffer->data_size);
    event.data = buffer->data;
    if (log_->writeEvent(&event) != 0) write_failed_ = true;
    gaps_.Observe(channel, buffer->data, buffer->data_size);
    ++per_channel_[channel];
  }

  const SequenceGaps& gaps() const { return gaps_; }
  const std::map<std::string, int64_t>& per_channel() const { return per_channel_; }
  bool write_failed() const { return write_failed_; }

 private:
  lcm::LogFile* log_;
  SequenceGaps gaps_;
  std::map<std::string, int64_t> per_channel_;
  bool write_failed_ = false;
};

// "1,367 messages on 8 channels in 93.2 s; missed 83 (uav0/SUBMAP 83)".
void PrintRecorded(const Recorder& recorder, const std::string& file, double seconds) {
  const SequenceGaps& gaps = recorder.gaps();
  std::fprintf(stderr, "stitch record: %" PRId64 " messages on %zu channels in %.1f s -> %s\n", gaps.messages(),
               recorder.per_channel().size(), seconds, file.c_str());
  std::string missed;
  for (const auto& [channel, count] : gaps.missed_by_channel()) {
    missed += (missed.empty() ? "" : ", ") + channel + " " + std::to_string(count);
  }
  if (gaps.missed() == 0) {
    std::fprintf(stderr, "stitch record: missed 0 (no gap in any sender's sequence numbers)\n");
  } else {
    std::fprintf(stderr,
                 "stitch record: WARNING: missed %" PRId64
                 " messages their senders numbered (%s): the bus dropped them before the recorder read them "
                 "(a machine too loaded, or a receive buffer capped low: net.core.rmem_max)\n",
                 gaps.missed(), missed.c_str());
  }
  if (gaps.unreadable() > 0 || gaps.implausible() > 0) {
    std::fprintf(stderr,
                 "stitch record: %" PRId64 " messages without a stitch header and %" PRId64
                 " implausible sequence jumps (recorded as they came)\n",
                 gaps.unreadable(), gaps.implausible());
  }
}

}  // namespace

int RecordCommand(int argc, char** argv) {
  std::vector<std::string> files;
  std::string lcm_url = bus::DefaultLcmUrl(), agents = "uav0";
  bool all = false, force = false;
  ArgParser args(
      "stitch record",
      "Records a flight's features until Ctrl-C (or SIGTERM) into an LCM log: for each aircraft its submap "
      "updates and requests, tracking and service statuses, its pose stream, sequence information, the global "
      "map and the map cloud (never images, unless --all). At the end it says how many messages it recorded "
      "and how many it missed (gaps in their senders' sequence numbers). `stitch map FILE` rebuilds the "
      "merged map from the recording; lcm-logplayer replays it onto a bus, where stitch-viewer shows it as "
      "it was flown.");
  args.AddPositional(&files, "FILE", "the LCM log to write");
  args.AddOption("--lcm-url", &lcm_url, "URL", "the bus to record (a udpm:// address gets a 2 MB receive buffer)");
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
             : "(SUBMAP|SUBMAP_REQUEST|TRACKING_STATUS|POSE|SERVICE|SEQUENCE|GLOBAL_MAP|MAP_CLOUD|GNSS)");
    const std::atomic<bool>& stop = InstallStopSignals();
    auto lcm = bus::OpenLcm(lcm_url);
    lcm::LogFile log(files[0], "w");
    if (!log.good()) throw Error("cannot write " + files[0]);
    Recorder recorder(&log);
    lcm->subscribe(channels, &Recorder::OnMessage, &recorder);
    std::fprintf(stderr, "stitch record: %s -> %s (Ctrl-C to stop)\n", channels.c_str(), files[0].c_str());
    const Stopwatch clock;
    int failures = 0;  // in a row; a stop signal also interrupts the wait (-1)
    while (!stop.load() && !recorder.write_failed()) {
      failures = lcm->handleTimeout(100) < 0 ? failures + 1 : 0;
      if (failures > 10 && !stop.load()) throw Error("the bus failed while recording");
    }
    PrintRecorded(recorder, files[0], clock.ElapsedSeconds());
    if (recorder.write_failed()) throw Error("writing " + files[0] + " failed (a full disk?); the log ends there");
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch record: %s\n", e.what());
    return 1;
  }
}

}  // namespace stitch
