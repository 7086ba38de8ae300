#pragma once
// A flight controller's GNSS fixes from its MAVLink stream: over UDP (ArduPilot's and PX4's
// telemetry output, or mavlink-router's) or straight from the serial port it is wired to (a UART
// or its USB port). A thread reads the datagrams sent to an address, or the port's bytes, decodes
// them (MavlinkGnssDecoder) and hands each fix, stamped with the wall clock at its arrival (the
// live camera's clock), to `on_fix`. A serial port that goes away (a controller rebooted, a USB
// cable pulled) is opened again every second.

#include <atomic>
#include <functional>
#include <mutex>
#include <string>
#include <thread>

#include "services/ingest/live_gnss.h"
#include "stitch/geo/mavlink_gnss.h"

namespace stitch {

struct MavlinkSerialPort {
  std::string device;  // e.g. /dev/ttyACM0, /dev/serial0
  int baud = 57600;    // ArduPilot's telemetry default; a USB port ignores it
};

class MavlinkReceiver : public LiveGnssReceiver {
 public:
  // Binds at once; throws stitch::Error for an address that is not ADDRESS:PORT or cannot be bound.
  MavlinkReceiver(const std::string& listen, const MavlinkGnssOptions& options, GnssFixCallback on_fix);
  // Opens the port at once (raw, 8N1, `baud`); throws stitch::Error for a rate it does not know or
  // a device it cannot open.
  MavlinkReceiver(const MavlinkSerialPort& port, const MavlinkGnssOptions& options, GnssFixCallback on_fix);
  ~MavlinkReceiver() override;
  MavlinkReceiver(const MavlinkReceiver&) = delete;
  MavlinkReceiver& operator=(const MavlinkReceiver&) = delete;

  MavlinkGnssCounts counts() const;
  int port() const { return port_; }  // UDP: the bound port (listen's, or the one chosen for port 0)
  std::string Describe() const;       // counts in words, for the log

 private:
  void Receive();
  void OpenSerial();  // throws stitch::Error

  int fd_ = -1;  // the UDP socket, or the serial port (-1 while it is away)
  int port_ = 0;
  MavlinkSerialPort serial_;  // its device is empty for UDP
  GnssFixCallback on_fix_;
  mutable std::mutex mutex_;
  MavlinkGnssDecoder decoder_;  // guarded by mutex_ (the thread decodes, counts() reads)
  int64_t reads_ = 0;           // datagrams, or reads of the serial port
  std::atomic<bool> running_{true};
  std::thread thread_;
};

}  // namespace stitch
