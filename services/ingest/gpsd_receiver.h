#pragma once
// Fixes from a GNSS receiver that gpsd serves (the Linux way to read one: gpsd owns the serial or
// USB device and speaks JSON on TCP port 2947), read through gpsd's own client library (libgps).
// Each TPV report with a 2D or 3D fix becomes a fix: the height above the ellipsoid (altHAE), the
// accuracy from epx/epy/epv (gpsd states them at 95% confidence: halved to 1 sigma; where it gives
// none, 3 m and 6 m), the fix type from gpsd's status (DGPS, RTK float and fixed), its time the
// receiver's (the report's UTC time carried onto the wall clock by the quickest arrival:
// ReceiverClock; a report without a time: its arrival), less the latency. A gpsd that is
// not there yet, or goes away, is tried again every second; that is said in the log, at most
// every 30 s.

#include <atomic>
#include <mutex>
#include <string>
#include <thread>

#include "services/ingest/live_gnss.h"
#include "stitch/geo/receiver_clock.h"

namespace stitch {

class GpsdReceiver : public LiveGnssReceiver {
 public:
  GpsdReceiver(std::string host, std::string port, double latency_s, GnssFixCallback on_fix);
  ~GpsdReceiver() override;

  std::string Describe() const override;
  int64_t fixes() const { return fixes_.load(); }

 private:
  void Receive();

  std::string host_, port_;
  double latency_s_;
  GnssFixCallback on_fix_;
  std::atomic<int64_t> fixes_{0}, without_fix_{0}, connections_{0};
  std::atomic<bool> running_{true};
  ReceiverClock clock_;  // the receive thread's
  std::thread thread_;
};

}  // namespace stitch
