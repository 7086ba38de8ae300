#include "services/ingest/gpsd_receiver.h"

#include <gps.h>

#include <chrono>
#include <cmath>
#include <mutex>

#include "stitch/util/log.h"
#include "stitch/util/time.h"

namespace stitch {
namespace {

constexpr double kStatedHorizontalAccuracyM = 3.0, kStatedVerticalAccuracyM = 6.0;
constexpr double kRetryS = 1.0, kSayAgainS = 30.0;

GnssFixType FixTypeOf(const gps_fix_t& fix) {
  if (fix.mode < MODE_2D) return GnssFixType::kNone;
  switch (fix.status) {
    case STATUS_DGPS_FIX:
      return GnssFixType::kDgps;
    case STATUS_RTK_FIX:
      return GnssFixType::kRtkFixed;
    case STATUS_RTK_FLT:
      return GnssFixType::kRtkFloat;
    default:
      return fix.mode == MODE_3D ? GnssFixType::k3d : GnssFixType::k2d;
  }
}

// libgps connects through getprotobyname, which is not thread-safe: receivers in one process (a
// test's) connect one at a time.
std::mutex& ConnectMutex() {
  static std::mutex connecting;
  return connecting;
}

// gpsd's 95% figure as one sigma, or `stated` where it gives none.
double Sigma(double at_95_percent, double stated) {
  return std::isfinite(at_95_percent) && at_95_percent > 0 ? at_95_percent / 2 : stated;
}

}  // namespace

GpsdReceiver::GpsdReceiver(std::string host, std::string port, double latency_s, GnssFixCallback on_fix)
    : host_(std::move(host)), port_(std::move(port)), latency_s_(latency_s), on_fix_(std::move(on_fix)) {
  thread_ = std::thread([this] { Receive(); });
}

GpsdReceiver::~GpsdReceiver() {
  running_ = false;
  thread_.join();
}

std::string GpsdReceiver::Describe() const {
  return std::to_string(fixes_.load()) + " GNSS fixes from gpsd at " + host_ + ":" + port_ + " (" +
         std::to_string(without_fix_.load()) + " reports without a usable fix, " + std::to_string(connections_.load()) +
         " connections)";
}

void GpsdReceiver::Receive() {
  gps_data_t data{};
  bool open = false;
  double said_at = -1e9;
  int64_t last_t_ns = 0;
  const auto say = [&](const std::string& what) {
    if (MonotonicSeconds() - said_at < kSayAgainS) return;
    said_at = MonotonicSeconds();
    STITCH_LOG(WARNING) << "gpsd at " << host_ << ":" << port_ << ": " << what << "; trying again every " << kRetryS
                        << " s";
  };
  while (running_.load()) {
    if (!open) {
      int opened;
      {
        std::lock_guard<std::mutex> lock(ConnectMutex());
        opened = gps_open(host_.c_str(), port_.c_str(), &data);
      }
      if (opened != 0) {
        say(std::string("cannot connect (") + gps_errstr(errno) + ")");
        for (int i = 0; i < 10 && running_.load(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(100));
        continue;
      }
      gps_stream(&data, WATCH_ENABLE | WATCH_JSON, nullptr);
      open = true;
      ++connections_;
      STITCH_LOG(INFO) << "reading GNSS fixes from gpsd at " << host_ << ":" << port_;
    }
    if (!gps_waiting(&data, 200000)) continue;  // microseconds
    char message[4096];
    if (gps_read(&data, message, sizeof(message)) < 0) {
      say("the connection was lost");
      gps_close(&data);
      open = false;
      continue;
    }
    // Only a TPV report (time, position, velocity) carries a fix; SKY, VERSION, DEVICES do not.
    if (!(data.set & MODE_SET) || std::string(message).find("\"class\":\"TPV\"") == std::string::npos) continue;
    const int64_t arrived_t_ns = WallClockNs();
    GnssFix fix;
    fix.type = FixTypeOf(data.fix);
    fix.position.latitude_deg = data.fix.latitude;
    fix.position.longitude_deg = data.fix.longitude;
    fix.position.height_m = std::isfinite(data.fix.altHAE) ? data.fix.altHAE : 0.0;
    const double horizontal_95 = std::isfinite(data.fix.epx) && std::isfinite(data.fix.epy)
                                     ? std::max(data.fix.epx, data.fix.epy)
                                     : data.fix.eph;
    fix.horizontal_accuracy_m = Sigma(horizontal_95, kStatedHorizontalAccuracyM);
    fix.vertical_accuracy_m = Sigma(data.fix.epv, kStatedVerticalAccuracyM);
    // A 2D fix has no height: it is kept, with the vertical accuracy of none.
    if (fix.type == GnssFixType::k2d) fix.vertical_accuracy_m = 1e4;
    if (!fix.usable() || !std::isfinite(data.fix.latitude) || !std::isfinite(data.fix.longitude) ||
        !WhyNotAFix(fix).empty()) {
      ++without_fix_;
      continue;
    }
    // The receiver's time of the fix (UTC), carried onto the wall clock by the quickest arrival
    // (ReceiverClock); a report without one: its arrival.
    const bool timed = (data.set & TIME_SET) && data.fix.time.tv_sec > 0;
    const int64_t receiver_t_ns =
        timed ? static_cast<int64_t>(data.fix.time.tv_sec) * 1'000'000'000 + static_cast<int64_t>(data.fix.time.tv_nsec)
              : 0;
    fix.t_ns =
        (timed ? clock_.Stamp(receiver_t_ns, arrived_t_ns) : arrived_t_ns) - static_cast<int64_t>(latency_s_ * 1e9);
    fix.t_ns = std::max(fix.t_ns, last_t_ns + 1);
    last_t_ns = fix.t_ns;
    ++fixes_;
    on_fix_(fix);
  }
  if (open) {
    gps_stream(&data, WATCH_DISABLE, nullptr);
    gps_close(&data);
  }
}

}  // namespace stitch
