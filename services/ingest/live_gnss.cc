#include "services/ingest/live_gnss.h"

#include "services/ingest/gpsd_receiver.h"
#include "services/ingest/mavlink_receiver.h"
#include "stitch/config/ingest_options.h"
#include "stitch/util/error.h"

namespace stitch {

std::unique_ptr<LiveGnssReceiver> OpenLiveGnssReceiver(const std::string& setting, double latency_s,
                                                       GnssFixCallback on_fix,
                                                       const std::optional<Secret>& mavlink_signing_key,
                                                       const std::string& signing_state_file) {
  if (const std::string why = WhyNotAGnssReceiver(setting); !why.empty() || setting.empty()) {
    throw Error(why.empty() ? "no GNSS receiver named" : why);
  }
  MavlinkGnssOptions options;
  options.latency_s = latency_s;
  options.signing_key = mavlink_signing_key;
  if (setting.rfind("mavlink-serial:", 0) == 0) {
    MavlinkSerialPort port;
    const std::string rest = setting.substr(15);
    const size_t colon = rest.rfind(':');
    port.device = rest.substr(0, colon);
    if (colon != std::string::npos) {
      try {
        port.baud = std::stoi(rest.substr(colon + 1));
      } catch (const std::exception&) {
        throw Error("ingest.gnss_receiver: '" + rest.substr(colon + 1) + "' is not a serial rate in baud");
      }
    }
    return std::make_unique<MavlinkReceiver>(port, options, std::move(on_fix), signing_state_file);
  }
  if (setting.rfind("mavlink:", 0) == 0) {
    return std::make_unique<MavlinkReceiver>(setting.substr(8), options, std::move(on_fix), signing_state_file);
  }
  if (mavlink_signing_key) {
    throw Error("ingest.gnss_signing_key_file is a MAVLink signing key: gpsd's fixes carry no signature");
  }
  std::string host = "localhost", port = "2947";
  if (setting != "gpsd") {
    const std::string address = setting.substr(5);
    const size_t colon = address.rfind(':');
    host = address.substr(0, colon);
    port = address.substr(colon + 1);
    if (host.empty()) host = "localhost";
  }
  return std::make_unique<GpsdReceiver>(host, port, latency_s, std::move(on_fix));
}

}  // namespace stitch
