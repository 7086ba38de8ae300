#pragma once
// A flight controller's GNSS fixes from its MAVLink stream: over UDP (ArduPilot's and PX4's
// telemetry output, or mavlink-router's) or straight from the serial port it is wired to (a UART
// or its USB port). A thread reads the datagrams sent to an address, or the port's bytes, decodes
// them (MavlinkGnssDecoder) and hands each fix, stamped with the wall clock at its arrival (the
// live camera's clock), to `on_fix`. A serial port that goes away (a controller rebooted, a USB
// cable pulled) is opened again every second.
//
// With a signing key and a state file, the newest signature timestamp accepted is kept there
// (written at most every 10 s, and when the receiver stops) and read back when a receiver starts,
// so that MAVLink's one-minute window for a stream not seen before holds across restarts: a
// signed frame recorded in an earlier run is refused by the next one too.

#include <atomic>
#include <functional>
#include <mutex>
#include <string>
#include <thread>

#include "services/ingest/live_gnss.h"
#include "stitch/geo/geoid.h"
#include "stitch/geo/mavlink_gnss.h"

namespace stitch {

struct MavlinkSerialPort {
  std::string device;  // e.g. /dev/ttyACM0, /dev/serial0
  int baud = 57600;    // ArduPilot's telemetry default; a USB port ignores it
};

class MavlinkReceiver : public LiveGnssReceiver {
 public:
  // Binds at once; throws stitch::Error for an address that is not ADDRESS:PORT or cannot be bound,
  // or a state file (`signing_state_file`, "": none) that holds no timestamp.
  MavlinkReceiver(const std::string& listen, const MavlinkGnssOptions& options, GnssFixCallback on_fix,
                  std::string signing_state_file = "");
  // Opens the port at once (raw, 8N1, `baud`); throws stitch::Error for a rate it does not know or
  // a device it cannot open, or a state file as above.
  MavlinkReceiver(const MavlinkSerialPort& port, const MavlinkGnssOptions& options, GnssFixCallback on_fix,
                  std::string signing_state_file = "");
  ~MavlinkReceiver() override;
  MavlinkReceiver(const MavlinkReceiver&) = delete;
  MavlinkReceiver& operator=(const MavlinkReceiver&) = delete;

  MavlinkGnssCounts counts() const;
  int port() const { return port_; }  // UDP: the bound port (listen's, or the one chosen for port 0)
  std::string Describe() const;       // counts in words, for the log

 private:
  void Receive();
  void OpenSerial();  // throws stitch::Error
  // `options` with the timestamp `state_file` keeps (none where the file is absent).
  static MavlinkGnssOptions WithStoredTimestamp(MavlinkGnssOptions options, const std::string& state_file);
  // Writes the newest signed timestamp to the state file when it moved (`force`: whatever the
  // time since the last write). Logs a file it cannot write, once.
  void KeepNewestSigned(bool force);

  int fd_ = -1;  // the UDP socket, or the serial port (-1 while it is away)
  int port_ = 0;
  MavlinkSerialPort serial_;  // its device is empty for UDP
  GnssFixCallback on_fix_;
  mutable std::mutex mutex_;
  std::string state_file_;
  MavlinkGnssDecoder decoder_;  // guarded by mutex_ (the thread decodes, counts() reads)
  uint64_t kept_signed_ = 0;    // the timestamp the state file holds
  double kept_at_s_ = 0;        // MonotonicSeconds() of its last write
  bool state_file_failed_ = false;
  int64_t reads_ = 0;       // datagrams, or reads of the serial port
  MslToEllipsoid heights_;  // the thread's: altitudes above mean sea level raised to the ellipsoid
  std::atomic<bool> running_{true};
  std::thread thread_;
};

}  // namespace stitch
