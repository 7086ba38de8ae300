#pragma once
// The skeleton every service's main() shares (services/*/main.cc): the common flags applied, the
// settings loaded (the file, --set, then the program's own flags), the stop signals, the bus and
// this agent's publisher; the service itself is the body's; any error ends the process with its
// message and status 1.
//
//   int main(int argc, char** argv) {
//     ServiceCommandLine common;
//     ArgParser args("stitch-mapper", "...");
//     common.Register(&args);
//     if (!args.Parse(argc, argv)) return args.exit_code();
//     return RunService("mapper", common, common.settings, [&](ServiceProcess& process) {
//       MapperService mapper(process.lcm, process.publisher, process.config.mapper, ...);
//       process.RunUntilStopped(mapper, ServiceProcess::StopOrder::kServiceFirst);
//       return 0;
//     });
//   }

#include <atomic>
#include <functional>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "services/common/bus.h"
#include "services/common/service.h"
#include "stitch/config/stitch_config.h"
#include "stitch/util/log.h"

namespace stitch {

struct ServiceProcess {
  const ServiceCommandLine& common;
  const StitchConfig& config;
  lcm::LCM* lcm;
  bus::Publisher* publisher;
  const std::atomic<bool>& stop;  // SIGINT or SIGTERM
  // The camera's frames (bus.frame_url), or the bus itself: only the ingest and the tracker use
  // them; RunUntilStopped dispatches it too.
  lcm::LCM* frame_lcm;
  bus::Publisher* frame_publisher;

  // The URL the camera's frames travel on.
  const std::string& frame_url() const { return frame_lcm != lcm ? config.bus.frame_url : common.lcm_url; }

  // Sleeps until SIGINT or SIGTERM.
  void WaitForStop() const;
  // Which stops first: the dispatcher (the service hears nothing more while it stops) or the
  // service (it still hears its peers while it stops: the mapper answers the merger's last
  // requests).
  enum class StopOrder { kBusFirst, kServiceFirst };
  // Starts the bus's dispatcher and `service`, waits for the stop signal (then `after_signal`,
  // with the bus still up), stops both in `order`.
  template <class Service>
  void RunUntilStopped(Service& service, StopOrder order, const std::function<void()>& after_signal = nullptr) const {
    bus::Dispatcher dispatcher(lcm);
    std::optional<bus::Dispatcher> frame_dispatcher;
    if (frame_lcm != lcm) frame_dispatcher.emplace(frame_lcm);
    dispatcher.Start();
    if (frame_dispatcher) frame_dispatcher->Start();
    service.Start();
    STITCH_LOG(INFO) << "listening on " << common.lcm_url
                     << (frame_dispatcher ? " (the camera's frames on " + frame_url() + ")" : std::string());
    WaitForStop();
    if (after_signal) after_signal();
    if (order == StopOrder::kBusFirst) {
      dispatcher.Stop();
      if (frame_dispatcher) frame_dispatcher->Stop();
    }
    service.Stop();
    dispatcher.Stop();
    if (frame_dispatcher) frame_dispatcher->Stop();
  }
};

// Applies the common flags for `service_name`, loads the settings (`settings`: --set's and the
// program's own flags as KEY=VALUE), opens the bus and runs `body`; returns its status, or 1 with
// the message on stderr when anything throws. A service that sends or takes the camera's frames
// (FrameBus::kOpen: the ingest, the tracker) also opens bus.frame_url where it is another bus;
// the others never do (a socket on it would receive every frame).
enum class FrameBus { kNone, kOpen };
int RunService(const std::string& service_name, const ServiceCommandLine& common,
               const std::vector<std::string>& settings, const std::function<int(ServiceProcess&)>& body,
               FrameBus frame_bus = FrameBus::kNone);

}  // namespace stitch
