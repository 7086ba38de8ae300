#include "services/ingest/mavlink_receiver.h"

#include <fcntl.h>
#include <poll.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <thread>

#include "services/common/udp_address.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "stitch/util/text_file.h"
#include "stitch/util/time.h"

namespace stitch {
namespace {
constexpr double kKeepSignedEvery_s = 10;  // the state file's writes, at most
constexpr char kStateKey[] = "newest_signed_timestamp";
}  // namespace

MavlinkGnssOptions MavlinkReceiver::WithStoredTimestamp(MavlinkGnssOptions options, const std::string& state_file) {
  if (state_file.empty() || !options.signing_key || !std::filesystem::exists(state_file)) return options;
  std::ifstream in(state_file);
  std::string key;
  unsigned long long timestamp = 0;
  if (!(in >> key >> timestamp) || key != kStateKey) {
    throw Error("ingest.gnss_signing_state_file " + state_file + " holds no '" + kStateKey +
                " N' line (remove it to start without: a replay of frames the last run took is then taken once)");
  }
  options.newest_signed_before = timestamp;
  STITCH_LOG(INFO) << "MAVLink signatures held to timestamp " << timestamp << " and newer (less a minute for a "
                   << "new stream), from " << state_file;
  return options;
}

void MavlinkReceiver::KeepNewestSigned(bool force) {
  if (state_file_.empty() || !decoder_.checks_signatures()) return;
  const uint64_t newest = decoder_.newest_signed();
  if (newest <= kept_signed_ || (!force && MonotonicSeconds() - kept_at_s_ < kKeepSignedEvery_s)) return;
  try {
    WriteFileAtomically(state_file_, std::string(kStateKey) + " " + std::to_string(newest) + "\n");
    kept_signed_ = newest;
    kept_at_s_ = MonotonicSeconds();
  } catch (const Error& e) {
    if (!state_file_failed_) {
      STITCH_LOG(WARNING) << e.what() << ": replays across a restart are not refused";
    }
    state_file_failed_ = true;
    kept_at_s_ = MonotonicSeconds();
  }
}

MavlinkReceiver::MavlinkReceiver(const std::string& listen, const MavlinkGnssOptions& options, GnssFixCallback on_fix,
                                 std::string signing_state_file)
    : on_fix_(std::move(on_fix)),
      state_file_(std::move(signing_state_file)),
      decoder_(WithStoredTimestamp(options, state_file_)),
      kept_signed_(decoder_.newest_signed()) {
  const sockaddr_in address = ResolveIpv4(listen, "ingest.gnss_receiver mavlink:");
  fd_ = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (fd_ < 0) throw Error(std::string("ingest.gnss_receiver: cannot open a UDP socket: ") + std::strerror(errno));
  if (bind(fd_, reinterpret_cast<const sockaddr*>(&address), sizeof(address)) != 0) {
    const std::string why = std::strerror(errno);
    close(fd_);
    throw Error("ingest.gnss_receiver: cannot listen on " + listen + ": " + why);
  }
  sockaddr_in bound{};
  socklen_t length = sizeof(bound);
  getsockname(fd_, reinterpret_cast<sockaddr*>(&bound), &length);
  port_ = ntohs(bound.sin_port);
  STITCH_LOG(INFO) << "listening for the flight controller's MAVLink GNSS fixes on " << FormatAddress(bound);
  thread_ = std::thread([this] { Receive(); });
}

namespace {

speed_t BaudRate(int baud) {
  switch (baud) {
    case 9600:
      return B9600;
    case 19200:
      return B19200;
    case 38400:
      return B38400;
    case 57600:
      return B57600;
    case 115200:
      return B115200;
    case 230400:
      return B230400;
    case 460800:
      return B460800;
    case 500000:
      return B500000;
    case 921600:
      return B921600;
    case 1000000:
      return B1000000;
    case 1500000:
      return B1500000;
    default:
      throw Error("ingest.gnss_receiver: a serial rate of " + std::to_string(baud) + " baud is not one it knows");
  }
}

}  // namespace

MavlinkReceiver::MavlinkReceiver(const MavlinkSerialPort& port, const MavlinkGnssOptions& options,
                                 GnssFixCallback on_fix, std::string signing_state_file)
    : serial_(port),
      on_fix_(std::move(on_fix)),
      state_file_(std::move(signing_state_file)),
      decoder_(WithStoredTimestamp(options, state_file_)),
      kept_signed_(decoder_.newest_signed()) {
  BaudRate(serial_.baud);
  OpenSerial();
  STITCH_LOG(INFO) << "reading the flight controller's MAVLink GNSS fixes from " << serial_.device << " at "
                   << serial_.baud << " baud";
  thread_ = std::thread([this] { Receive(); });
}

void MavlinkReceiver::OpenSerial() {
  const int fd = open(serial_.device.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) throw Error("ingest.gnss_receiver: cannot open " + serial_.device + ": " + std::strerror(errno));
  termios settings{};
  if (tcgetattr(fd, &settings) == 0) {  // a pseudo-terminal or a USB port takes these too
    cfmakeraw(&settings);
    settings.c_cflag |= CLOCAL | CREAD;
    settings.c_cflag &= ~(CSTOPB | PARENB | CRTSCTS);
    cfsetispeed(&settings, BaudRate(serial_.baud));
    cfsetospeed(&settings, BaudRate(serial_.baud));
    tcsetattr(fd, TCSANOW, &settings);
  }
  fd_ = fd;
}

MavlinkReceiver::~MavlinkReceiver() {
  running_ = false;
  if (thread_.joinable()) thread_.join();
  if (fd_ >= 0) close(fd_);
  std::lock_guard<std::mutex> lock(mutex_);
  KeepNewestSigned(/*force=*/true);
}

MavlinkGnssCounts MavlinkReceiver::counts() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return decoder_.counts();
}

std::string MavlinkReceiver::Describe() const {
  std::lock_guard<std::mutex> lock(mutex_);
  const MavlinkGnssCounts& c = decoder_.counts();
  return std::to_string(c.fixes) + " GNSS fixes from MAVLink (" + std::to_string(reads_) +
         (serial_.device.empty() ? " datagrams, " : " reads of " + serial_.device + ", ") + std::to_string(c.frames) +
         " frames read, " + std::to_string(c.damaged) + " damaged, " + std::to_string(c.refused) +
         " position messages without a usable fix, " + std::to_string(c.bytes_skipped) +
         " bytes of other messages or garbage" +
         (decoder_.checks_signatures()
              ? ", " + std::to_string(c.unsigned_frames) + " unsigned, " + std::to_string(c.bad_signatures) +
                    " with a wrong signature, " + std::to_string(c.replayed) + " replayed"
              : std::string()) +
         ")";
}

void MavlinkReceiver::Receive() {
  uint8_t buffer[65536];
  const bool serial = !serial_.device.empty();
  while (running_.load()) {
    if (fd_ < 0) {  // the serial port went away: try it again every second
      for (int i = 0; i < 10 && running_.load(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(100));
      if (!running_.load()) break;
      try {
        OpenSerial();
        STITCH_LOG(INFO) << serial_.device << " is back";
      } catch (const Error&) {
      }
      continue;
    }
    pollfd ready{fd_, POLLIN, 0};
    if (poll(&ready, 1, 100) <= 0) continue;
    const ssize_t size = read(fd_, buffer, sizeof(buffer));
    if (size < 0 && (errno == EAGAIN || errno == EINTR)) continue;
    if (size <= 0) {
      if (serial) {  // unplugged, or the other end closed: read again once it is back
        STITCH_LOG(WARNING) << serial_.device << ": " << (size == 0 ? "closed" : std::strerror(errno))
                            << "; opening it again every second";
        close(fd_);
        fd_ = -1;
      }
      continue;
    }
    std::vector<GnssFix> fixes;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      ++reads_;
      // A datagram holds whole frames; a serial port's bytes come in any pieces.
      fixes = serial ? decoder_.Feed(buffer, static_cast<size_t>(size), WallClockNs())
                     : decoder_.FeedDatagram(buffer, static_cast<size_t>(size), WallClockNs());
      KeepNewestSigned(/*force=*/false);
    }
    if (const std::string why = heights_.Raise(&fixes); !why.empty()) {
      STITCH_LOG(WARNING) << "the flight controller's altitudes above mean sea level are sent as they are (the map "
                             "will sit the geoid's height off vertically): "
                          << why;
    }
    for (const GnssFix& fix : fixes) on_fix_(fix);
  }
}

}  // namespace stitch
