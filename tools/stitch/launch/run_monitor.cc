#include "tools/stitch/launch/run_monitor.h"

#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <thread>

#include "services/common/convert.h"
#include "stitch/util/time.h"

namespace stitch {

namespace {
// How often each service's resident memory goes to memory.tsv.
constexpr double kMemorySampleSeconds = 2.0;
}  // namespace

RunMonitor::RunMonitor(lcm::LCM* lcm, const std::string& agent, std::optional<bus::BusAuthenticator> authenticator)
    : subscriber_(lcm, std::move(authenticator)) {
  snapshot_.last_change = MonotonicSeconds();
  subscriber_.Subscribe<stitch::tracking_status_t>(
      bus::Channel(agent, bus::kTrackingStatus),
      [this](std::unique_ptr<stitch::tracking_status_t> s, const std::string&) {
        std::lock_guard<std::mutex> lock(mutex_);
        if (s->frame_index > snapshot_.highest_frame) {
          snapshot_.highest_frame = s->frame_index;
          snapshot_.latest = *s;
        }
        ++snapshot_.statuses;
        snapshot_.last_change = MonotonicSeconds();
      });
  subscriber_.Subscribe<stitch::service_status_t>(
      bus::Channel(agent, bus::kService), [this](std::unique_ptr<stitch::service_status_t> s, const std::string&) {
        std::lock_guard<std::mutex> lock(mutex_);
        snapshot_.services[s->service] = *s;
      });
}

RunMonitor::Snapshot RunMonitor::Get() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return snapshot_;
}

std::string WatchFlight(const LaunchPlan& plan, const RunMonitor& monitor, RunServices& services,
                        const std::atomic<bool>& stop, bool quiet, RunInfo* info) {
  const bool tty = isatty(STDOUT_FILENO) && !quiet;
  const Stopwatch clock;
  const int frames = plan.source.num_frames;
  int last_decile = 0;
  double ingest_done_at = -1, memory_sampled_at = -1e9;
  std::string failure;
  while (true) {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    const RunMonitor::Snapshot snapshot = monitor.Get();
    const int done = snapshot.highest_frame + 1;
    const double seconds = clock.ElapsedSeconds();
    if (seconds - memory_sampled_at >= kMemorySampleSeconds) {
      memory_sampled_at = seconds;
      services.SampleMemory(seconds, snapshot.highest_frame);
    }
    const double fps = seconds > 0 ? done / seconds : 0;
    if (tty) {
      std::printf("\r  frame %5d/%d  %5.1f fps  tracker %-12s submap %-6s keyframes %d   ", done, frames, fps,
                  snapshot.statuses ? MessageStateName(snapshot.latest.state) : "starting",
                  SubmapName(SubmapId(snapshot.latest.submap_id)).c_str(), snapshot.latest.submap_keyframes);
      std::fflush(stdout);
    } else if (!quiet && frames > 0 && done * 10 / frames > last_decile) {
      last_decile = done * 10 / frames;
      std::printf("  frame %d/%d, %.1f fps\n", done, frames, fps);
      std::fflush(stdout);
    }
    if (stop.load()) {
      info->interrupted = true;
      break;
    }
    failure = services.Failure();
    if (!failure.empty()) break;
    if (ingest_done_at < 0 && services.IngestDone()) ingest_done_at = seconds;
    if (ingest_done_at >= 0) {
      // Ingest has finished; the tracker is done once it has reported the last frame, or has been
      // quiet for a while (frames lost on the way never come).
      const bool caught_up = snapshot.highest_frame >= frames - 1;
      const bool quiet_for_a_while = MonotonicSeconds() - snapshot.last_change > 3.0 && seconds - ingest_done_at > 3.0;
      if (caught_up || quiet_for_a_while) break;
    }
  }
  if (tty) std::printf("\n");
  return failure;
}

}  // namespace stitch
