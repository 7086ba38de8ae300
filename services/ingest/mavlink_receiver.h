#pragma once
// A flight controller's GNSS fixes from its MAVLink stream over UDP (ArduPilot's and PX4's
// telemetry output, or a serial port forwarded by mavlink-router): a thread that reads the
// datagrams sent to `listen` (ADDRESS:PORT), decodes them (MavlinkGnssDecoder) and hands each fix,
// stamped with the wall clock at its arrival (the live camera's clock), to `on_fix`.

#include <atomic>
#include <functional>
#include <mutex>
#include <string>
#include <thread>

#include "services/ingest/live_gnss.h"
#include "stitch/geo/mavlink_gnss.h"

namespace stitch {

class MavlinkReceiver : public LiveGnssReceiver {
 public:
  // Binds at once; throws stitch::Error for an address that is not ADDRESS:PORT or cannot be bound.
  MavlinkReceiver(const std::string& listen, const MavlinkGnssOptions& options, GnssFixCallback on_fix);
  ~MavlinkReceiver() override;
  MavlinkReceiver(const MavlinkReceiver&) = delete;
  MavlinkReceiver& operator=(const MavlinkReceiver&) = delete;

  MavlinkGnssCounts counts() const;
  int port() const { return port_; }  // the bound port (listen's, or the one chosen for port 0)
  std::string Describe() const;       // counts in words, for the log

 private:
  void Receive();

  int socket_ = -1;
  int port_ = 0;
  GnssFixCallback on_fix_;
  mutable std::mutex mutex_;
  MavlinkGnssDecoder decoder_;  // guarded by mutex_ (the thread decodes, counts() reads)
  int64_t datagrams_ = 0;
  std::atomic<bool> running_{true};
  std::thread thread_;
};

}  // namespace stitch
