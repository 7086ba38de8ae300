#include "services/ingest/mavlink_receiver.h"

#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "services/common/udp_address.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "stitch/util/time.h"

namespace stitch {
MavlinkReceiver::MavlinkReceiver(const std::string& listen, const MavlinkGnssOptions& options, GnssFixCallback on_fix)
    : on_fix_(std::move(on_fix)), decoder_(options) {
  const sockaddr_in address = ResolveIpv4(listen, "ingest.gnss_receiver mavlink:");
  socket_ = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (socket_ < 0) throw Error(std::string("ingest.gnss_receiver: cannot open a UDP socket: ") + std::strerror(errno));
  if (bind(socket_, reinterpret_cast<const sockaddr*>(&address), sizeof(address)) != 0) {
    const std::string why = std::strerror(errno);
    close(socket_);
    throw Error("ingest.gnss_receiver: cannot listen on " + listen + ": " + why);
  }
  sockaddr_in bound{};
  socklen_t length = sizeof(bound);
  getsockname(socket_, reinterpret_cast<sockaddr*>(&bound), &length);
  port_ = ntohs(bound.sin_port);
  STITCH_LOG(INFO) << "listening for the flight controller's MAVLink GNSS fixes on " << FormatAddress(bound);
  thread_ = std::thread([this] { Receive(); });
}

MavlinkReceiver::~MavlinkReceiver() {
  running_ = false;
  if (thread_.joinable()) thread_.join();
  close(socket_);
}

MavlinkGnssCounts MavlinkReceiver::counts() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return decoder_.counts();
}

std::string MavlinkReceiver::Describe() const {
  std::lock_guard<std::mutex> lock(mutex_);
  const MavlinkGnssCounts& c = decoder_.counts();
  return std::to_string(c.fixes) + " GNSS fixes from MAVLink (" + std::to_string(datagrams_) + " datagrams, " +
         std::to_string(c.frames) + " frames read, " + std::to_string(c.damaged) + " damaged, " +
         std::to_string(c.refused) + " position messages without a usable fix, " + std::to_string(c.bytes_skipped) +
         " bytes of other messages or garbage)";
}

void MavlinkReceiver::Receive() {
  uint8_t buffer[65536];
  while (running_.load()) {
    pollfd ready{socket_, POLLIN, 0};
    if (poll(&ready, 1, 100) <= 0) continue;
    const ssize_t size = recv(socket_, buffer, sizeof(buffer), 0);
    if (size <= 0) continue;
    std::vector<GnssFix> fixes;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      ++datagrams_;
      fixes = decoder_.FeedDatagram(buffer, static_cast<size_t>(size), WallClockNs());
    }
    for (const GnssFix& fix : fixes) on_fix_(fix);
  }
}

}  // namespace stitch
