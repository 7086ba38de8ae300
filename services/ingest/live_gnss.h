#pragma once
// A live camera's GNSS receiver (ingest.gnss_receiver): a thread of its own that hands each fix,
// on the wall clock (the clock live frames carry) less a latency, to a callback: the receiver's
// own time of the fix carried onto the wall clock by its quickest arrival (ReceiverClock), or,
// where the receiver gives none, the fix's arrival. Two kinds: a receiver gpsd serves (gpsd_receiver.h), and a flight
// controller's MAVLink telemetry on UDP (mavlink_receiver.h).

#include <functional>
#include <memory>
#include <optional>
#include <string>

#include "services/common/secret_file.h"
#include "stitch/geo/gnss_fix.h"

namespace stitch {

using GnssFixCallback = std::function<void(const GnssFix&)>;

class LiveGnssReceiver {
 public:
  virtual ~LiveGnssReceiver() = default;     // stops its thread
  virtual std::string Describe() const = 0;  // what it received, in words, for the log
};

// The receiver `setting` names (gpsd, gpsd:HOST:PORT, mavlink:ADDRESS:PORT: WhyNotAGnssReceiver);
// throws stitch::Error for a setting that names none, or an address it cannot listen on.
// `mavlink_signing_key`: a MAVLink receiver takes only frames signed with it (mavlink_gnss.h),
// keeping the newest signature timestamp in `signing_state_file` across runs ("": not kept);
// with gpsd, an error.
std::unique_ptr<LiveGnssReceiver> OpenLiveGnssReceiver(const std::string& setting, double latency_s,
                                                       GnssFixCallback on_fix,
                                                       const std::optional<Secret>& mavlink_signing_key = {},
                                                       const std::string& signing_state_file = "");

}  // namespace stitch
