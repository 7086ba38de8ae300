#include "services/common/bus.h"

#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <random>

namespace stitch::bus {

void CheckAgentName(const std::string& agent) {
  const bool valid = !agent.empty() && agent.size() <= 32 && std::all_of(agent.begin(), agent.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-';
  });
  if (!valid) {
    throw Error("agent name '" + agent + "' must be 1-32 letters, digits, '_' or '-' (it prefixes channel names)");
  }
}

std::string Channel(const std::string& agent, const char* suffix) {
  CheckAgentName(agent);
  return agent + "/" + suffix;
}

uint32_t MaxMessageBytes(const std::string& channel) {
  const std::string suffix = channel.substr(channel.find('/') + 1);
  for (const char* large : {kFrame, kKeyframe, kLocalMap, kSubmap, kGlobalMap, kMapCloud}) {
    if (suffix == large) return kMaxMessageBytes;
  }
  if (suffix == kKeyframeImage || suffix == kMosaicTile) return 9u << 20;
  for (const char* small :
       {kFrameAck, kSequence, kTrackingStatus, kSubmapRequest, kService, kLinkStatus, kPose, kGnss}) {
    if (suffix == small) return 1u << 20;
  }
  return kMaxMessageBytes;  // a channel of another program
}

std::vector<std::string> SplitAgents(const std::string& list) {
  std::vector<std::string> agents;
  size_t start = 0;
  while (start <= list.size() && !list.empty()) {
    const size_t comma = std::min(list.find(',', start), list.size());
    agents.push_back(list.substr(start, comma - start));
    CheckAgentName(agents.back());
    start = comma + 1;
  }
  return agents;
}

std::string DefaultLcmUrl() {
  return LocalUdpUrl(7667);
}

std::string LocalUdpUrl(int port) {
  return WithReceiveBuffer("udpm://239.255.76.67:" + std::to_string(port) + "?ttl=0");
}

std::string WithReceiveBuffer(const std::string& url) {
  if (url.rfind("udpm://", 0) != 0 || url.find("recv_buf_size=") != std::string::npos) return url;
  return url + (url.find('?') == std::string::npos ? "?" : "&") +
         "recv_buf_size=" + std::to_string(kReceiveBufferBytes);
}

namespace {

// A bind without SO_REUSEADDR fails while any socket (LCM's share theirs) holds the port.
// `type`: SOCK_DGRAM or SOCK_STREAM.
bool PortFree(int port, int type) {
  const int fd = socket(AF_INET, type, 0);
  if (fd < 0) return false;
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_ANY);
  address.sin_port = htons(static_cast<uint16_t>(port));
  const bool free = bind(fd, reinterpret_cast<const sockaddr*>(&address), sizeof(address)) == 0;
  close(fd);
  return free;
}

std::vector<int> UnusedPorts(int n, int first, int count, int type) {
  std::random_device device;
  std::vector<int> ports;
  int port = first;
  for (int attempt = 0; attempt < 200 * n && static_cast<int>(ports.size()) < n; ++attempt) {
    port = first + static_cast<int>(device() % static_cast<unsigned>(std::max(count, 1)));
    if (std::find(ports.begin(), ports.end(), port) == ports.end() && PortFree(port, type)) ports.push_back(port);
  }
  while (static_cast<int>(ports.size()) < n) ports.push_back(port);  // every port tried is held
  return ports;
}

}  // namespace

std::vector<int> UnusedUdpPorts(int n, int first, int count) {
  return UnusedPorts(n, first, count, SOCK_DGRAM);
}

int UnusedUdpPort(int first, int count) {
  return UnusedUdpPorts(1, first, count).front();
}

int UnusedTcpPort(int first, int count) {
  return UnusedPorts(1, first, count, SOCK_STREAM).front();
}

std::string UnusedLocalUdpUrl() {
  return LocalUdpUrl(UnusedUdpPort());
}

std::unique_ptr<lcm::LCM> OpenLcm(const std::string& given_url) {
  const std::string url = WithReceiveBuffer(given_url);
  auto lcm = std::make_unique<lcm::LCM>(url);
  if (!lcm->good()) {
    throw Error("cannot open LCM at '" + url +
                "': for udpm:// the machine needs a multicast route (on a host without network: "
                "`ip route add 224.0.0.0/4 dev lo` and `ip link set lo multicast on`), or use memq:// "
                "for a single process");
  }
  return lcm;
}

Publisher::Publisher(lcm::LCM* lcm, std::string agent, std::optional<BusAuthenticator> authenticator)
    : lcm_(lcm), agent_(std::move(agent)), authenticator_(std::move(authenticator)) {
  CheckAgentName(agent_);
  std::random_device device;
  session_ =
      static_cast<int64_t>((static_cast<uint64_t>(device()) << 31) ^ device() ^ static_cast<uint64_t>(WallUtime())) &
      0x7fffffffffffffffLL;
}

Publisher::Publisher(lcm::LCM* lcm, const Publisher& same_sender)
    : lcm_(lcm),
      agent_(same_sender.agent_),
      authenticator_(same_sender.authenticator_),
      session_(same_sender.session_) {}

Subscriber::Subscriber(lcm::LCM* lcm, std::optional<BusAuthenticator> authenticator)
    : lcm_(lcm), authenticator_(std::move(authenticator)) {}

Subscriber::~Subscriber() {
  for (auto* subscription : subscriptions_) lcm_->unsubscribe(subscription);
}

void Subscriber::Reject(const std::string& channel, const std::string& why) {
  const int64_t count = ++rejected_;
  // At most one line per second, so a flood of garbage cannot flood the log.
  const int64_t now = WallUtime();
  int64_t last = last_reject_log_us_.load();
  if (now - last > 1'000'000 && last_reject_log_us_.compare_exchange_strong(last, now)) {
    STITCH_LOG(WARNING) << "dropped a message on " << channel << ": it " << why << " (" << count << " dropped so far)";
  }
}

Dispatcher::Dispatcher(lcm::LCM* lcm) : lcm_(lcm) {}

Dispatcher::~Dispatcher() {
  Stop();
}

void Dispatcher::Start() {
  if (running_.exchange(true)) return;
  thread_ = std::thread([this] {
    while (running_.load()) {
      if (lcm_->handleTimeout(50) < 0) {
        STITCH_LOG(ERROR) << "LCM handle failed; the bus is down";
        std::this_thread::sleep_for(std::chrono::milliseconds(200));
      }
    }
  });
}

void Dispatcher::Stop() {
  running_ = false;
  if (thread_.joinable()) thread_.join();
}

}  // namespace stitch::bus
