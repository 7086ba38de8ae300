#pragma once
// What every service process shares: the stop signal, the heartbeat, and the common options
// (bus URL, agent, config file, log level).

#include <atomic>
#include <functional>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "services/common/bus.h"
#include "stitch/service_status_t.hpp"
#include "stitch/util/args.h"

namespace stitch {

// Sets the flag on SIGINT or SIGTERM (once per process). The handler only stores to an atomic.
const std::atomic<bool>& InstallStopSignals();

struct ServiceCommandLine {
  std::string lcm_url = bus::DefaultLcmUrl();
  std::string agent = "uav0";
  std::string config_path;            // YAML with one section per service; empty: defaults
  std::vector<std::string> settings;  // --set KEY=VALUE, over the file (and a program's own flags)
  std::string log_level = "info";

  void Register(ArgParser* args);
  // Applies the log level and tag; throws stitch::Error for a bad level or agent.
  void Apply(const std::string& service_name) const;
};

// Publishes the service's state on <agent>/SERVICE about once a second and on every change.
class Heartbeat {
 public:
  struct Counts {
    int64_t items_in = 0, items_out = 0, items_rejected = 0;
  };
  Heartbeat(bus::Publisher* publisher, std::string service, std::function<Counts()> counts);
  ~Heartbeat();
  // Changes the state (STATE_* of service_status_t) and publishes at once.
  void SetState(int8_t state, const std::string& detail = "");
  void Start();
  void Stop();

 private:
  void PublishNow();

  bus::Publisher* publisher_;
  std::string service_;
  std::function<Counts()> counts_;
  std::mutex mutex_;
  int8_t state_ = stitch::service_status_t::STATE_STARTING;
  std::string detail_;
  std::atomic<bool> running_{false};
  std::thread thread_;
};

}  // namespace stitch
