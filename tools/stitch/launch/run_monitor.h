#pragma once
// What the launcher hears on the aircraft's bus while the flight plays (the tracker's statuses,
// the services' heartbeats), and the watch over the flight: progress on the terminal, memory
// samples, and the moment the run is over (ingest has played everything and the tracker has
// caught up, a service failed, or Ctrl-C).

#include <atomic>
#include <map>
#include <mutex>
#include <string>

#include "services/common/bus.h"
#include "stitch/service_status_t.hpp"
#include "stitch/tracking_status_t.hpp"
#include "tools/stitch/launch/run_services.h"

namespace stitch {

class RunMonitor {
 public:
  // Subscribes at once: construct before the Dispatcher starts.
  // `authenticator`: the bus key's, where the run's bus has one (bus.key_file).
  RunMonitor(lcm::LCM* lcm, const std::string& agent,
             std::optional<bus::BusAuthenticator> authenticator = std::nullopt);

  struct Snapshot {
    int highest_frame = -1;  // the tracker's newest frame
    int64_t statuses = 0;
    stitch::tracking_status_t latest{};
    double last_change = 0;  // MonotonicSeconds() of the last status
    std::map<std::string, stitch::service_status_t> services;
  };
  Snapshot Get() const;

 private:
  bus::Subscriber subscriber_;
  mutable std::mutex mutex_;
  Snapshot snapshot_;
};

// Watches the flight until it is over; returns why it failed ("" when it ended well). Sets
// `info->interrupted` on Ctrl-C (`stop`).
std::string WatchFlight(const LaunchPlan& plan, const RunMonitor& monitor, RunServices& services,
                        const std::atomic<bool>& stop, bool quiet, RunInfo* info);

}  // namespace stitch
