#include "services/common/service_main.h"

#include <chrono>
#include <cstdio>

namespace stitch {

void ServiceProcess::WaitForStop() const {
  while (!stop.load()) std::this_thread::sleep_for(std::chrono::milliseconds(50));
}

int RunService(const std::string& service_name, const ServiceCommandLine& common,
               const std::vector<std::string>& settings, const std::function<int(ServiceProcess&)>& body) {
  try {
    common.Apply(service_name);
    const StitchConfig config = LoadStitchConfig(common.config_path, settings);
    const auto& stop = InstallStopSignals();
    auto lcm = bus::OpenLcm(common.lcm_url);
    bus::Publisher publisher(lcm.get(), common.agent, bus::BusAuthenticator::FromSetting(config.bus.key_file));
    ServiceProcess process{common, config, lcm.get(), &publisher, stop};
    return body(process);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch-%s: %s\n", service_name.c_str(), e.what());
    return 1;
  }
}

}  // namespace stitch
