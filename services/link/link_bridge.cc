#include "services/link/link_bridge.h"

#include <arpa/inet.h>
#include <netdb.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <sstream>

#include "services/common/bus.h"
#include "services/common/udp_address.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "stitch/util/time.h"

namespace stitch {
namespace {

constexpr size_t kMaxMessageBytes = 64u << 20;      // larger messages are refused, both ways
constexpr size_t kMaxIncompleteBytes = 256u << 20;  // reassembly memory; beyond it the oldest is given up
constexpr size_t kMaxRetainedBytes = 256u << 20;    // repair memory; beyond it the oldest is forgotten
constexpr uint64_t kMaxRepairScan = 10000;          // messages looked at per repair pass
constexpr double kEchoLifetimeS = 5.0;

}  // namespace

LinkBridge::LinkBridge(lcm::LCM* lcm, LinkOptions options, std::optional<bus::BusAuthenticator> bus_authenticator)
    : lcm_(lcm),
      options_(std::move(options)),
      bus_authenticator_(std::move(bus_authenticator)),
      session_(static_cast<uint64_t>(WallUtime())),
      impairment_rng_(static_cast<uint64_t>(options_.seed) * 0x9E3779B97F4A7C15ULL + 1) {
  std::string why;
  if (!options_.Check(&why)) throw Error(why);
  if (!options_.key_file.empty()) {
    const link::LinkKey key = link::LoadKeyFile(options_.key_file);
    if (options_.side.empty()) {
      throw Error(
          "link.side: say which bridge of the pair this is (aircraft or ground; --side): each direction has its own "
          "key, derived from the pair's");
    }
    sealer_.emplace(link::DirectionKey(key, options_.side), session_);
    opener_.emplace(link::DirectionKey(key, link::OtherSide(options_.side)));
    seal_overhead_ = link::kSealOverheadBytes;
  } else if (!options_.insecure) {
    throw Error(
        "the link needs a key both bridges share: make one with `stitch link keygen FILE`, copy it to "
        "both sides and give it as link.key_file (or set link.insecure: true to run unauthenticated)");
  }
  datagram_bytes_ = options_.max_datagram_bytes - seal_overhead_;
  try {
    accept_ = std::regex(options_.accept, std::regex::extended);
  } catch (const std::regex_error& e) {
    throw Error("link.accept '" + options_.accept + "' is not a regular expression: " + e.what());
  }
  try {
    background_ = std::regex(options_.background, std::regex::extended);
  } catch (const std::regex_error& e) {
    throw Error("link.background '" + options_.background + "' is not a regular expression: " + e.what());
  }
  const sockaddr_in listen = ResolveIpv4(options_.listen, "link.listen");
  const sockaddr_in peer = ResolveIpv4(options_.peer, "link.peer");
  peer_address_ = peer;
  socket_ = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (socket_ < 0) throw Error(std::string("cannot open a UDP socket: ") + std::strerror(errno));
  const int buffer_bytes = 4 << 20;
  setsockopt(socket_, SOL_SOCKET, SO_RCVBUF, &buffer_bytes, sizeof(buffer_bytes));
  setsockopt(socket_, SOL_SOCKET, SO_SNDBUF, &buffer_bytes, sizeof(buffer_bytes));
  if (bind(socket_, reinterpret_cast<const sockaddr*>(&listen), sizeof(listen)) != 0) {
    const std::string error = std::strerror(errno);
    close(socket_);
    throw Error("cannot listen on UDP " + options_.listen + ": " + error +
                " (another bridge on that port, or an address this machine does not have?)");
  }
  sockaddr_in bound{};
  socklen_t length = sizeof(bound);
  getsockname(socket_, reinterpret_cast<sockaddr*>(&bound), &length);
  local_port_ = ntohs(bound.sin_port);
  tokens_ = burst_bytes_;
  tokens_at_ = MonotonicSeconds();
  subscription_ = lcm_->subscribe(options_.forward, &LinkBridge::OnLocalMessage, this);
  subscription_->setQueueCapacity(bus::kSubscriptionQueueCapacity);
  STITCH_LOG(INFO) << "link: sending '" << options_.forward << "' to " << FormatAddress(peer) << ", receiving on "
                   << FormatAddress(bound)
                   << (options_.budget_bytes_per_s > 0
                           ? ", budget " + std::to_string(static_cast<int64_t>(options_.budget_bytes_per_s)) + " B/s"
                           : ", no budget");
  if (!sealer_) {
    STITCH_LOG(WARNING) << "link: insecure: datagrams are not authenticated; anyone who reaches " << options_.listen
                        << " from the peer's address is believed";
  }
  if (options_.loss > 0 || options_.delay_ms > 0 || options_.jitter_ms > 0) {
    STITCH_LOG(WARNING) << "link: injecting impairments: loss " << options_.loss << ", delay " << options_.delay_ms
                        << " ms, jitter " << options_.jitter_ms << " ms";
  }
}

LinkBridge::~LinkBridge() {
  Stop();
  if (subscription_) lcm_->unsubscribe(subscription_);
  if (socket_ >= 0) close(socket_);
}

void LinkBridge::Start() {
  if (running_.exchange(true)) return;
  sender_ = std::thread([this] { SendLoop(); });
  receiver_ = std::thread([this] { ReceiveLoop(); });
}

void LinkBridge::Stop() {
  if (!running_.exchange(false)) return;
  wake_.notify_all();
  if (sender_.joinable()) sender_.join();
  if (receiver_.joinable()) receiver_.join();
}

LinkCounts LinkBridge::counts() const {
  // Never both locks at once here: the sender takes mutex_, then counts_mutex_ (found by
  // ThreadSanitizer: the reverse order here could deadlock against it).
  LinkCounts counts;
  {
    std::lock_guard<std::mutex> lock(counts_mutex_);
    counts = counts_;
  }
  std::lock_guard<std::mutex> queue_lock(mutex_);
  counts.queued_bytes = static_cast<int64_t>(queued_bytes_);
  const double now = MonotonicSeconds();
  for (const auto* queue : {&small_queue_, &large_queue_, &background_queue_}) {
    if (!queue->empty()) counts.oldest_wait_s = std::max(counts.oldest_wait_s, now - queue->front().queued_at);
  }
  const double heard = last_heard_s_.load();
  counts.seconds_since_peer = heard < 0 ? -1 : now - heard;
  return counts;
}

size_t LinkBridge::backlog() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return small_queue_.size() + large_queue_.size() + background_queue_.size() + repairs_.size() +
         (small_sending_ ? 1 : 0) + (large_sending_ ? 1 : 0) + (background_sending_ ? 1 : 0) + (pending_ ? 1 : 0) +
         delay_line_.size();
}

bool LinkBridge::Settled(double quiet_s) const {
  return backlog() == 0 && MonotonicSeconds() - last_repair_request_s_.load() > quiet_s;
}

stitch::link_status_t LinkBridge::Status(double rate_bytes_per_s) const {
  const LinkCounts c = counts();
  stitch::link_status_t status{};
  status.forward = options_.forward;
  status.peer = options_.peer;
  status.budget_bytes_per_s = options_.budget_bytes_per_s;
  status.send_rate_bytes_per_s = rate_bytes_per_s;
  status.queued_bytes = c.queued_bytes;
  status.backlog_s = options_.budget_bytes_per_s > 0 ? c.queued_bytes / options_.budget_bytes_per_s : c.oldest_wait_s;
  status.bytes_sent = c.bytes_sent;
  status.messages_sent = c.messages_sent;
  status.messages_expired = c.messages_expired;
  status.fragments_repaired = c.fragments_repaired;
  status.messages_received = c.messages_delivered;
  status.messages_given_up = c.messages_given_up;
  status.datagrams_refused = c.datagrams_refused;
  status.datagrams_unauthenticated = c.datagrams_unauthenticated;
  status.datagrams_replayed = c.datagrams_replayed;
  status.authenticated = sealer_.has_value();
  status.seconds_since_peer = c.seconds_since_peer;
  return status;
}

std::string LinkBridge::Describe() const {
  const LinkCounts c = counts();
  std::ostringstream text;
  text << "sent " << c.messages_sent << " messages in " << c.datagrams_sent << " datagrams, " << c.bytes_sent / 1000
       << " kB";
  if (c.queued_bytes > 0) text << ", " << c.queued_bytes / 1000 << " kB waiting";
  if (c.messages_expired > 0) text << ", " << c.messages_expired << " expired unsent";
  if (c.datagrams_lost_injected > 0) text << ", " << c.datagrams_lost_injected << " datagrams dropped on purpose";
  text << "; repaired " << c.fragments_repaired << " fragments, asked " << c.repair_requests_sent << " times; received "
       << c.messages_delivered << " messages";
  if (c.messages_given_up > 0) text << ", gave up on " << c.messages_given_up;
  if (c.local_unauthenticated > 0) {
    text << "; refused " << c.local_unauthenticated << " messages on this side's bus without its tag";
  }
  if (c.datagrams_refused > 0) {
    text << ", refused " << c.datagrams_refused << " datagrams (" << c.datagrams_unauthenticated << " unauthenticated, "
         << c.datagrams_replayed << " replayed)";
  }
  return text.str();
}

uint64_t LinkBridge::EchoKey(const std::string& channel, const uint8_t* data, size_t size) {
  uint64_t hash = 0xcbf29ce484222325ULL;  // FNV-1a
  for (char c : channel) hash = (hash ^ static_cast<uint8_t>(c)) * 0x100000001b3ULL;
  hash = (hash ^ 0xff) * 0x100000001b3ULL;
  for (size_t i = 0; i < size; ++i) hash = (hash ^ data[i]) * 0x100000001b3ULL;
  return hash ^ size;
}

void LinkBridge::OnLocalMessage(const lcm::ReceiveBuffer* buffer, const std::string& channel) {
  const auto* data = static_cast<const uint8_t*>(buffer->data);
  const double now = MonotonicSeconds();
  {
    std::lock_guard<std::mutex> lock(echo_mutex_);
    const auto echo = echo_keys_.find(EchoKey(channel, data, buffer->data_size));
    if (echo != echo_keys_.end() && echo->second > now) {
      echo_keys_.erase(echo);
      std::lock_guard<std::mutex> counts_lock(counts_mutex_);
      ++counts_.echoes_suppressed;
      return;
    }
  }
  // On a keyed bus, only what its services tagged crosses, without the tag (the other side tags
  // what it publishes with its own bus's key).
  size_t size = buffer->data_size;
  if (bus_authenticator_) {
    if (!bus_authenticator_->Verify(channel, data, size)) {
      if (unauthenticated_log_.Allow()) {
        STITCH_LOG(WARNING) << "link: a message on " << channel
                            << " does not carry this bus's tag (forged, or from a sender without bus.key_file); "
                               "not sent";
      }
      std::lock_guard<std::mutex> counts_lock(counts_mutex_);
      ++counts_.local_unauthenticated;
      return;
    }
    size -= bus::kBusTagBytes;
  }
  if (size > kMaxMessageBytes || link::FragmentCount(channel, size, datagram_bytes_) == 0) {
    if (too_large_log_.Allow()) {
      STITCH_LOG(WARNING) << "link: a message of " << size << " bytes on " << channel
                          << " is too large to send (or its channel name too long); dropped";
    }
    std::lock_guard<std::mutex> counts_lock(counts_mutex_);
    ++counts_.messages_refused;
    return;
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    Outgoing outgoing{channel, std::string(reinterpret_cast<const char*>(data), size), now};
    queued_bytes_ += outgoing.bytes.size();
    const bool small = static_cast<int>(outgoing.bytes.size()) <= options_.small_message_bytes;
    if (std::regex_match(channel, background_)) {
      background_queue_.push_back(std::move(outgoing));
    } else {
      (small ? small_queue_ : large_queue_).push_back(std::move(outgoing));
    }
  }
  {
    std::lock_guard<std::mutex> counts_lock(counts_mutex_);
    ++counts_.messages_queued;
  }
  wake_.notify_one();
}

void LinkBridge::QueueControl(std::string datagram) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    control_.push_back(std::move(datagram));
  }
  wake_.notify_one();
}

void LinkBridge::ExpireLocked(double now) {
  int64_t expired = 0;
  for (auto* queue : {&small_queue_, &large_queue_, &background_queue_}) {
    while (!queue->empty() && now - queue->front().queued_at > options_.max_queue_s) {
      queued_bytes_ -= queue->front().bytes.size();
      queue->pop_front();
      ++expired;
    }
  }
  if (expired > 0) {
    if (expired_log_.Allow()) {
      STITCH_LOG(WARNING) << "link: dropped " << expired << " messages that waited over " << options_.max_queue_s
                          << " s: the flight sends more than the budget of " << options_.budget_bytes_per_s << " B/s";
    }
    std::lock_guard<std::mutex> counts_lock(counts_mutex_);
    counts_.messages_expired += expired;
  }
  while (!retained_.empty()) {
    const Retained& oldest = retained_.begin()->second;
    if (!oldest.sent || (now - oldest.sent_at <= options_.retain_s && retained_bytes_ <= kMaxRetainedBytes)) break;
    retained_bytes_ -= oldest.bytes.size();
    retained_.erase(retained_.begin());
  }
}

std::optional<std::string> LinkBridge::NextDatagramLocked(double now) {
  if (!control_.empty()) {
    std::string datagram = std::move(control_.front());
    control_.pop_front();
    return datagram;
  }
  while (!repairs_.empty()) {
    const auto [message, index] = repairs_.front();
    repairs_.pop_front();
    repairs_waiting_.erase({message, index});
    const auto retained = retained_.find(message);
    if (retained == retained_.end()) continue;
    std::lock_guard<std::mutex> counts_lock(counts_mutex_);
    ++counts_.fragments_repaired;
    return link::Encode(link::MakeFragment(session_, message, retained->second.channel, retained->second.bytes,
                                           datagram_bytes_, index));
  }
  // A background message, once begun, goes on to its end before a large one (only small messages
  // pass it): held half-sent it would hold back the end of what was sent, below which the
  // receiver asks for its lost datagrams, for as long as larger messages keep coming (a saturated
  // link stopped repairing, gave up on its messages and had them all sent again).
  const bool small_waits = small_sending_ || !small_queue_.empty();
  if (background_sending_ && !small_waits) return NextFragmentLocked(&background_sending_, now);
  for (auto [queue, sending] : {std::pair(&small_queue_, &small_sending_), std::pair(&large_queue_, &large_sending_),
                                std::pair(&background_queue_, &background_sending_)}) {
    if (!*sending && !queue->empty()) {
      Outgoing outgoing = std::move(queue->front());
      queue->pop_front();
      queued_bytes_ -= outgoing.bytes.size();
      *sending =
          Sending{next_message_, link::FragmentCount(outgoing.channel, outgoing.bytes.size(), datagram_bytes_), 0};
      retained_bytes_ += outgoing.bytes.size();
      retained_[next_message_++] = Retained{std::move(outgoing.channel), std::move(outgoing.bytes), false, 0};
    }
    if (*sending) return NextFragmentLocked(sending, now);
  }
  return std::nullopt;
}

std::string LinkBridge::NextFragmentLocked(std::optional<Sending>* sending, double now) {
  Sending& s = **sending;
  Retained& message = retained_[s.message];
  std::string datagram =
      link::Encode(link::MakeFragment(session_, s.message, message.channel, message.bytes, datagram_bytes_, s.next));
  if (++s.next == s.count) {
    message.sent = true;
    message.sent_at = now;
    sending->reset();
    std::lock_guard<std::mutex> counts_lock(counts_mutex_);
    ++counts_.messages_sent;
  }
  return datagram;
}

uint64_t LinkBridge::SentEndLocked() const {
  uint64_t end = next_message_;
  for (const auto* sending : {&small_sending_, &large_sending_, &background_sending_}) {
    if (*sending) end = std::min(end, (*sending)->message);
  }
  return end;
}

void LinkBridge::Transmit(std::string datagram, double now) {
  if (sealer_) datagram = sealer_->Seal(datagram);
  {
    std::lock_guard<std::mutex> counts_lock(counts_mutex_);
    ++counts_.datagrams_sent;
    counts_.bytes_sent += static_cast<int64_t>(datagram.size()) + link::kUdpIpHeaderBytes;
    if (options_.loss > 0 && impairment_rng_.Uniform() < options_.loss) {
      ++counts_.datagrams_lost_injected;
      return;
    }
  }
  const double delay_s =
      1e-3 * (options_.delay_ms + (options_.jitter_ms > 0 ? impairment_rng_.Uniform(0, options_.jitter_ms) : 0));
  if (delay_s > 0) {
    delay_line_.push(Delayed{now + delay_s, delay_order_++, std::move(datagram)});
    return;
  }
  SendNow(datagram);
}

void LinkBridge::SendDue(double now) {
  while (!delay_line_.empty() && delay_line_.top().due <= now) {
    SendNow(delay_line_.top().bytes);
    delay_line_.pop();
  }
}

void LinkBridge::SendNow(const std::string& datagram) {
  const auto* peer = reinterpret_cast<const sockaddr*>(&peer_address_);
  for (int attempt = 0; attempt < 20; ++attempt) {
    if (sendto(socket_, datagram.data(), datagram.size(), MSG_DONTWAIT, peer, sizeof(peer_address_)) >= 0) return;
    if (errno != EAGAIN && errno != EWOULDBLOCK && errno != ENOBUFS) break;
    pollfd writable{socket_, POLLOUT, 0};  // the socket's buffer is full: wait a little
    poll(&writable, 1, 5);
  }
  if (send_failed_log_.Allow()) {
    STITCH_LOG(WARNING) << "link: sending to " << options_.peer << " failed: " << std::strerror(errno);
  }
}

void LinkBridge::SendLoop() {
  double next_status = 0;
  double next_report = MonotonicSeconds() + options_.report_interval_s;
  while (running_.load()) {
    double now = MonotonicSeconds();
    SendDue(now);
    std::optional<std::string> datagram;
    double wait_s = 0.02;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (now >= next_status) {
        const uint64_t sent_end = SentEndLocked();
        const uint64_t retained_begin = retained_.empty() ? sent_end : std::min(sent_end, retained_.begin()->first);
        control_.push_back(link::Encode(link::LinkStatus{session_, sent_end, retained_begin}));
        next_status = now + options_.status_interval_s;
      }
      ExpireLocked(now);
      if (!pending_) pending_ = NextDatagramLocked(now);
      if (pending_) {
        const double cost = static_cast<double>(pending_->size() + seal_overhead_ + link::kUdpIpHeaderBytes);
        if (options_.budget_bytes_per_s <= 0) {
          datagram = std::move(pending_);
        } else {
          tokens_ = std::min(burst_bytes_, tokens_ + (now - tokens_at_) * options_.budget_bytes_per_s);
          tokens_at_ = now;
          if (tokens_ >= cost) {
            tokens_ -= cost;
            datagram = std::move(pending_);
          } else {
            wait_s = (cost - tokens_) / options_.budget_bytes_per_s;
          }
        }
        if (datagram) pending_.reset();
      }
    }
    if (datagram) {
      Transmit(std::move(*datagram), now);
      continue;
    }
    if (options_.report_interval_s > 0 && now >= next_report) {
      STITCH_LOG(INFO) << "link: " << Describe();
      next_report = now + options_.report_interval_s;
    }
    wait_s = std::min(wait_s, next_status - now);
    if (!delay_line_.empty()) wait_s = std::min(wait_s, delay_line_.top().due - now);
    std::unique_lock<std::mutex> lock(mutex_);
    if (control_.empty() && repairs_.empty() && wait_s > 0) {
      wake_.wait_for(lock, std::chrono::duration<double>(std::max(wait_s, 0.0002)));
    }
  }
}

void LinkBridge::ReceiveLoop() {
  std::vector<uint8_t> buffer(65536);
  const sockaddr_in& peer = peer_address_;
  double next_repair_pass = 0, next_echo_sweep = 0;
  while (running_.load()) {
    pollfd readable{socket_, POLLIN, 0};
    poll(&readable, 1, 10);
    while (true) {
      sockaddr_in from{};
      socklen_t from_length = sizeof(from);
      const ssize_t size = recvfrom(socket_, buffer.data(), buffer.size(), MSG_DONTWAIT,
                                    reinterpret_cast<sockaddr*>(&from), &from_length);
      if (size < 0) break;
      std::string why;
      link::Datagram datagram;
      std::string opened;
      const uint8_t* bytes = buffer.data();
      size_t length = static_cast<size_t>(size);
      link::Opener::Verdict verdict = link::Opener::Verdict::kOpened;
      bool reflected = false;
      if (peer.sin_addr.s_addr != INADDR_ANY &&
          (from.sin_addr.s_addr != peer.sin_addr.s_addr || from.sin_port != peer.sin_port)) {
        why = "comes from " + FormatAddress(from) + ", not the peer " + options_.peer;
      } else if (opener_ && (verdict = opener_->Open(bytes, length, &opened)) != link::Opener::Verdict::kOpened) {
        why = verdict == link::Opener::Verdict::kReplayed ? "was accepted before (replayed) or is an earlier run's"
                                                          : "fails authentication (forged, or sealed with another key)";
      } else {
        if (opener_) {
          bytes = reinterpret_cast<const uint8_t*>(opened.data());
          length = opened.size();
        }
        if (!link::Decode(bytes, length, &datagram, &why)) {
          why += " (" + std::to_string(size) + " bytes from " + FormatAddress(from) + ")";
        } else if ((datagram.type == link::DatagramType::kData && datagram.data.session == session_) ||
                   (datagram.type == link::DatagramType::kStatus && datagram.status.session == session_)) {
          // Sealed by this bridge's own key it would not open here; unsealed (insecure) it would
          // pass for the peer restarting, and cut the link.
          why = "is this bridge's own, sent back to it (reflected)";
          reflected = true;
        }
      }
      if (!why.empty()) {
        if (refused_log_.Allow()) {
          STITCH_LOG(WARNING) << "link: refused a datagram: " << why;
        }
        std::lock_guard<std::mutex> counts_lock(counts_mutex_);
        ++counts_.datagrams_refused;
        counts_.datagrams_unauthenticated += verdict == link::Opener::Verdict::kUnauthenticated;
        counts_.datagrams_replayed += verdict == link::Opener::Verdict::kReplayed || reflected;
        continue;
      }
      last_heard_s_ = MonotonicSeconds();
      Handle(datagram, MonotonicSeconds());
    }
    const double now = MonotonicSeconds();
    if (now >= next_repair_pass) {
      RequestRepairs(now);
      next_repair_pass = now + 0.02;
    }
    if (now >= next_echo_sweep) {
      std::lock_guard<std::mutex> lock(echo_mutex_);
      for (auto it = echo_keys_.begin(); it != echo_keys_.end();)
        it = it->second < now ? echo_keys_.erase(it) : std::next(it);
      next_echo_sweep = now + 1.0;
    }
  }
}

bool LinkBridge::AcceptSession(uint64_t session) {
  if (session == peer_session_) return true;
  if (session < peer_session_) return false;  // an earlier run of the other side, still in flight
  if (peer_session_ != 0) {
    STITCH_LOG(WARNING) << "link: the other side restarted; starting afresh with it";
  }
  peer_session_ = session;
  floor_ = 0;
  floor_known_ = false;
  peer_sent_end_ = 0;
  incomplete_.clear();
  finished_.clear();
  incomplete_bytes_ = 0;
  return true;
}

void LinkBridge::OnStatus(const link::LinkStatus& status) {
  if (!AcceptSession(status.session)) return;
  peer_sent_end_ = std::max(peer_sent_end_, status.sent_end);
  if (!floor_known_) {
    // The first word from this session: everything it still keeps is wanted (a bridge that
    // comes up late receives the last retain_s of the other side), and whatever came before.
    floor_ = status.retained_begin;
    if (!finished_.empty()) floor_ = std::min(floor_, *finished_.begin());
    if (!incomplete_.empty()) floor_ = std::min(floor_, incomplete_.begin()->first);
    floor_known_ = true;
    while (finished_.count(floor_)) finished_.erase(floor_++);
    return;
  }
  if (status.retained_begin <= floor_) return;
  // What the other side no longer keeps cannot be repaired.
  for (auto it = incomplete_.begin(); it != incomplete_.end() && it->first < status.retained_begin;) {
    incomplete_bytes_ -= it->second.bytes.size();
    it = incomplete_.erase(it);
  }
  uint64_t finished_below = 0;
  while (!finished_.empty() && *finished_.begin() < status.retained_begin) {
    finished_.erase(finished_.begin());
    ++finished_below;
  }
  const int64_t given_up = static_cast<int64_t>(status.retained_begin - floor_ - finished_below);
  floor_ = status.retained_begin;
  while (finished_.count(floor_)) finished_.erase(floor_++);
  if (given_up > 0) {
    std::lock_guard<std::mutex> counts_lock(counts_mutex_);
    counts_.messages_given_up += given_up;
  }
}

void LinkBridge::Handle(const link::Datagram& datagram, double now) {
  switch (datagram.type) {
    case link::DatagramType::kData:
      OnData(datagram.data, now);
      break;
    case link::DatagramType::kRepair:
      OnRepair(datagram.repair);
      break;
    case link::DatagramType::kStatus:
      OnStatus(datagram.status);
      break;
  }
}

void LinkBridge::OnData(const link::DataFragment& fragment, double now) {
  if (!AcceptSession(fragment.session)) return;
  if ((floor_known_ && fragment.message < floor_) || finished_.count(fragment.message)) return;  // a duplicate
  std::string why;
  if (fragment.message_bytes > kMaxMessageBytes)
    why = "a message of " + std::to_string(fragment.message_bytes) + " bytes";
  if (fragment.message > floor_ + 1000000) why = "message number far ahead of the rest";
  const bool refused_channel = !std::regex_match(fragment.channel, accept_);
  if (refused_channel) {
    why = "a message on " + fragment.channel + ", which this side does not take from the other (link.accept)";
  }
  Partial* partial = nullptr;
  if (why.empty()) {
    partial = &incomplete_[fragment.message];
    if (partial->count == 0) {
      partial->count = fragment.count;
      partial->channel = fragment.channel;
      partial->bytes.assign(fragment.message_bytes, '\0');
      partial->have.assign(fragment.count, false);
      incomplete_bytes_ += fragment.message_bytes;
    } else if (partial->count != fragment.count || partial->bytes.size() != fragment.message_bytes ||
               partial->channel != fragment.channel) {
      why = "a fragment that disagrees with the rest of its message";
    }
  }
  if (!why.empty()) {
    if (refused_log_.Allow()) {
      STITCH_LOG(WARNING) << "link: refused " << why;
    }
    {
      std::lock_guard<std::mutex> counts_lock(counts_mutex_);
      ++counts_.datagrams_refused;
    }
    if (refused_channel && fragment.message <= floor_ + 1000000) Finish(fragment.message);  // never asked for again
    return;
  }
  if (partial->have[fragment.index]) return;
  std::memcpy(partial->bytes.data() + fragment.offset, fragment.payload.data(), fragment.payload.size());
  partial->have[fragment.index] = true;
  partial->received_bytes += fragment.payload.size();
  partial->last_progress = now;
  if (++partial->received == partial->count) {
    if (partial->received_bytes == partial->bytes.size()) {
      Deliver(fragment.message, partial);
    } else {  // fragments that overlap or leave holes: not from a bridge of ours
      Finish(fragment.message);
      std::lock_guard<std::mutex> counts_lock(counts_mutex_);
      ++counts_.datagrams_refused;
      ++counts_.messages_given_up;
    }
  }
  // Bounded reassembly memory: the oldest unfinished message goes first.
  while (incomplete_bytes_ > kMaxIncompleteBytes && !incomplete_.empty()) {
    Finish(incomplete_.begin()->first);
    std::lock_guard<std::mutex> counts_lock(counts_mutex_);
    ++counts_.messages_given_up;
  }
}

void LinkBridge::Deliver(uint64_t message, Partial* partial) {
  if (bus_authenticator_) {
    const auto tag = bus_authenticator_->TagOf(
        partial->channel, reinterpret_cast<const uint8_t*>(partial->bytes.data()), partial->bytes.size());
    partial->bytes.append(reinterpret_cast<const char*>(tag.data()), tag.size());
  }
  {
    std::lock_guard<std::mutex> lock(echo_mutex_);
    echo_keys_[EchoKey(partial->channel, reinterpret_cast<const uint8_t*>(partial->bytes.data()),
                       partial->bytes.size())] = MonotonicSeconds() + kEchoLifetimeS;
  }
  lcm_->publish(partial->channel, partial->bytes.data(), static_cast<unsigned int>(partial->bytes.size()));
  {
    std::lock_guard<std::mutex> counts_lock(counts_mutex_);
    ++counts_.messages_delivered;
  }
  Finish(message);
}

void LinkBridge::Finish(uint64_t message) {
  const auto it = incomplete_.find(message);
  if (it != incomplete_.end()) {
    incomplete_bytes_ -= it->second.bytes.size();
    incomplete_.erase(it);
  }
  if (!floor_known_) {
    finished_.insert(message);  // the floor is set by the first status
    return;
  }
  if (message >= floor_) finished_.insert(message);
  while (finished_.count(floor_)) finished_.erase(floor_++);
}

void LinkBridge::RequestRepairs(double now) {
  if (peer_session_ == 0 || !floor_known_) return;
  link::RepairRequest request{peer_session_, {}};
  int64_t given_up = 0;
  const uint64_t end = std::min(peer_sent_end_, floor_ + kMaxRepairScan);
  for (uint64_t message = floor_; message < end; ++message) {
    if (finished_.count(message)) continue;
    auto [it, fresh] = incomplete_.try_emplace(message);
    Partial& partial = it->second;
    if (fresh) partial.last_progress = now;  // known to be sent only now: allow it the usual time
    if (now - partial.last_progress < 1e-3 * options_.repair_after_ms) continue;
    if (partial.rounds >= options_.repair_rounds) {
      Finish(message);
      ++given_up;
      continue;
    }
    link::RepairRequest::Wanted wanted{message, {}};
    for (int i = 0; i < partial.count; ++i) {
      if (!partial.have[i]) wanted.missing.push_back(static_cast<uint16_t>(i));
    }
    request.wanted.push_back(std::move(wanted));
    ++partial.rounds;
    partial.last_progress = now;
  }
  if (given_up > 0) {
    if (given_up_log_.Allow()) {
      STITCH_LOG(WARNING) << "link: gave up on " << given_up << " messages after " << options_.repair_rounds
                          << " requests for their lost datagrams";
    }
    std::lock_guard<std::mutex> counts_lock(counts_mutex_);
    counts_.messages_given_up += given_up;
  }
  if (request.wanted.empty()) return;
  const auto parts = link::SplitRepair(request, datagram_bytes_);
  for (const auto& part : parts) QueueControl(link::Encode(part));
  std::lock_guard<std::mutex> counts_lock(counts_mutex_);
  counts_.repair_requests_sent += static_cast<int64_t>(parts.size());
}

void LinkBridge::OnRepair(const link::RepairRequest& request) {
  if (request.session != session_) return;  // about an earlier run of this bridge
  last_repair_request_s_ = MonotonicSeconds();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& wanted : request.wanted) {
      const auto retained = retained_.find(wanted.message);
      if (retained == retained_.end() || !retained->second.sent) continue;
      const int count = link::FragmentCount(retained->second.channel, retained->second.bytes.size(), datagram_bytes_);
      const auto ask = [&](int index) {
        if (index < count && repairs_waiting_.insert({wanted.message, static_cast<uint16_t>(index)}).second) {
          repairs_.emplace_back(wanted.message, static_cast<uint16_t>(index));
        }
      };
      if (wanted.missing.empty()) {
        for (int i = 0; i < count; ++i) ask(i);
      } else {
        for (uint16_t index : wanted.missing) ask(index);
      }
    }
  }
  wake_.notify_one();
}

}  // namespace stitch
