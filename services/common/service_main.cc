#include "services/common/service_main.h"

#include <chrono>
#include <cstdio>
#include <memory>
#include <optional>

namespace stitch {

void ServiceProcess::WaitForStop() const {
  while (!stop.load()) std::this_thread::sleep_for(std::chrono::milliseconds(50));
}

int RunService(const std::string& service_name, const ServiceCommandLine& common,
               const std::vector<std::string>& settings, const std::function<int(ServiceProcess&)>& body,
               FrameBus frame_bus) {
  try {
    common.Apply(service_name);
    const StitchConfig config = LoadStitchConfig(common.config_path, settings);
    ApplyProcessSettings(config);
    const auto& stop = InstallStopSignals();
    auto lcm = bus::OpenLcm(common.lcm_url);
    bus::Publisher publisher(lcm.get(), common.agent, bus::BusAuthenticator::FromSetting(config.bus.key_file));
    const bool own_frame_bus =
        frame_bus == FrameBus::kOpen && !config.bus.frame_url.empty() && config.bus.frame_url != common.lcm_url;
    std::unique_ptr<lcm::LCM> frame_lcm = own_frame_bus ? bus::OpenLcm(config.bus.frame_url) : nullptr;
    std::optional<bus::Publisher> frame_publisher;
    if (frame_lcm) frame_publisher.emplace(frame_lcm.get(), publisher);
    ServiceProcess process{common,
                           config,
                           lcm.get(),
                           &publisher,
                           stop,
                           frame_lcm ? frame_lcm.get() : lcm.get(),
                           frame_publisher ? &*frame_publisher : &publisher};
    return body(process);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch-%s: %s\n", service_name.c_str(), e.what());
    return 1;
  }
}

}  // namespace stitch
