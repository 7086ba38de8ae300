#pragma once
// The bus: LCM with stitch's conventions. Channels carry an agent prefix ("uav0/FRAME"); every
// message starts with a header (agent, sender session, per-channel sequence number, utime).
//
// Threading: one Dispatcher thread per LCM instance runs LCM's handle loop and calls the
// subscription handlers; handlers should only decode-and-enqueue. Publisher is thread-safe.
// In tests, several services share one `memq://` instance and one Dispatcher.

#include <algorithm>
#include <atomic>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <lcm/lcm-cpp.hpp>

#include "services/common/bus_auth.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "stitch/util/time.h"

namespace stitch::bus {

// Messages LCM keeps per subscription while the dispatcher is busy.
inline constexpr int kSubscriptionQueueCapacity = 2000;
// The largest message a subscriber decodes (LCM itself carries up to 256 MB). Decoding costs at
// most a few times a message's size in memory (lcmtypes/stitch_lcm/decode_bounds.hpp), so this
// bounds what one message can make a service allocate; stitch's largest messages are frames
// (8.3 MB: a 4K camera's gray frame at full size) and submap parts (under 1 MB).
inline constexpr uint32_t kMaxMessageBytes = 32u << 20;
// The largest message a subscriber decodes on `channel`, by its suffix: kMaxMessageBytes for
// frames, keyframes, submaps and maps; 9 MB for a keyframe's picture and a mosaic tile (each at
// most 8 MB of image); 1 MB for statuses, acks, poses, fixes and requests, which are a few
// hundred bytes (a forged 32 MB status cost a service about 100 MB to decode).
uint32_t MaxMessageBytes(const std::string& channel);

// Channel suffixes.
inline constexpr char kFrame[] = "FRAME";
inline constexpr char kFrameAck[] = "FRAME_ACK";
inline constexpr char kSequence[] = "SEQUENCE";
inline constexpr char kTrackingStatus[] = "TRACKING_STATUS";
inline constexpr char kKeyframe[] = "KEYFRAME";
inline constexpr char kLocalMap[] = "LOCAL_MAP";
inline constexpr char kSubmap[] = "SUBMAP";
inline constexpr char kSubmapRequest[] = "SUBMAP_REQUEST";
inline constexpr char kGlobalMap[] = "GLOBAL_MAP";
inline constexpr char kService[] = "SERVICE";
inline constexpr char kLinkStatus[] = "LINK_STATUS";
inline constexpr char kPose[] = "POSE";
inline constexpr char kMapCloud[] = "MAP_CLOUD";
inline constexpr char kGnss[] = "GNSS";
inline constexpr char kKeyframeImage[] = "KEYFRAME_IMAGE";
inline constexpr char kMosaicTile[] = "MOSAIC_TILE";

// "uav0" + "FRAME" -> "uav0/FRAME". Throws stitch::Error for an agent name that is not
// [A-Za-z0-9_-]{1,32} (channels are regular expressions to LCM).
std::string Channel(const std::string& agent, const char* suffix);
void CheckAgentName(const std::string& agent);
// "uav0,uav1" -> {"uav0", "uav1"}, each checked; "" -> {}.
std::vector<std::string> SplitAgents(const std::string& list);

// LCM's default multicast group with ttl=0: nothing leaves this machine.
std::string DefaultLcmUrl();
// udpm URL on the default group with a given port, ttl=0 (tests and `stitch run` use their own).
std::string LocalUdpUrl(int port);
// `n` distinct UDP ports in [first, first + count) (by default below Linux's ephemeral range)
// that no socket on this machine is bound to now, picked at random: runs and tests side by side
// then never hear each other, as ports derived from process ids did (neighbouring tests get
// neighbouring ids). When every port tried is held, the last one tried fills the rest.
std::vector<int> UnusedUdpPorts(int n, int first = 20000, int count = 12000);
int UnusedUdpPort(int first = 20000, int count = 12000);  // UnusedUdpPorts(1, ...)
// A TCP port in [first, first + count) that no socket holds now, the same way: for a web server
// a test starts (18000-19999, below the UDP ones).
int UnusedTcpPort(int first = 18000, int count = 2000);
// LocalUdpUrl(UnusedUdpPort()).
std::string UnusedLocalUdpUrl();

// A udpm:// URL that names no receive buffer gets kReceiveBufferBytes (LCM's default is the
// kernel's, about 200 kB: a recorder beside a flight lost 83 of 1,367 submap messages); any
// other URL is returned as it is. Where the kernel caps the buffer lower (net.core.rmem_max),
// LCM says so on stderr when it opens.
inline constexpr int kReceiveBufferBytes = 2097152;
std::string WithReceiveBuffer(const std::string& url);

// Opens LCM (WithReceiveBuffer), throwing stitch::Error with what to check when it cannot (no
// multicast route...).
std::unique_ptr<lcm::LCM> OpenLcm(const std::string& url);

// Stamps the header of each message and publishes it; with a bus key (bus_auth.h), with its tag
// after it. Thread-safe.
class Publisher {
 public:
  Publisher(lcm::LCM* lcm, std::string agent, std::optional<BusAuthenticator> authenticator = std::nullopt);
  // Another LCM instance of the same sender (the frame bus): the same agent, key and session.
  Publisher(lcm::LCM* lcm, const Publisher& same_sender);

  template <class Message>
  void Publish(const std::string& channel, Message* message) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      message->header.agent = agent_;
      message->header.sender_session = session_;
      message->header.seq = next_seq_[channel]++;
      message->header.utime = WallUtime();
    }
    int status = 0;
    if (authenticator_) {
      const int size = message->getEncodedSize();
      std::vector<uint8_t> bytes(static_cast<size_t>(size) + kBusTagBytes);
      message->encode(bytes.data(), 0, size);
      const auto tag = authenticator_->TagOf(channel, bytes.data(), static_cast<size_t>(size));
      std::copy(tag.begin(), tag.end(), bytes.begin() + size);
      status = lcm_->publish(channel, bytes.data(), static_cast<unsigned int>(bytes.size()));
    } else {
      status = lcm_->publish(channel, message);
    }
    if (status != 0) {
      STITCH_LOG(WARNING) << "publish on " << channel << " failed (message of " << message->getEncodedSize()
                          << " bytes)";
    }
  }
  const std::string& agent() const { return agent_; }
  int64_t session() const { return session_; }
  // The bus key's authenticator, where this side's bus has one: the services' subscribers take it.
  const std::optional<BusAuthenticator>& authenticator() const { return authenticator_; }

 private:
  lcm::LCM* lcm_;
  std::string agent_;
  std::optional<BusAuthenticator> authenticator_;
  int64_t session_;
  std::mutex mutex_;
  std::map<std::string, int64_t> next_seq_;
};

// Owns subscriptions on one LCM instance and unsubscribes them when destroyed (destroy it before
// the LCM instance, and only while no Dispatcher is running on it).
//
// Each message is decoded into a fresh object handed to the handler. A message that does not
// decode (wrong type fingerprint, truncated, trailing bytes, absurd sizes) or whose header names
// another agent than its channel is dropped, counted and logged; it never reaches the handler.
// With a bus key, so is one without its valid tag, and one this subscription has taken before.
class Subscriber {
 public:
  explicit Subscriber(lcm::LCM* lcm, std::optional<BusAuthenticator> authenticator = std::nullopt);
  ~Subscriber();
  Subscriber(const Subscriber&) = delete;
  Subscriber& operator=(const Subscriber&) = delete;

  template <class Message>
  void Subscribe(const std::string& channel,
                 std::function<void(std::unique_ptr<Message>, const std::string& channel)> handler) {
    const std::string expected_agent = channel.substr(0, channel.find('/'));
    const uint32_t max_bytes = MaxMessageBytes(channel);
    auto replays = authenticator_ ? std::make_shared<ReplayGuard>() : nullptr;
    auto raw = std::make_unique<RawHandler>(
        [this, handler, expected_agent, replays, max_bytes](const lcm::ReceiveBuffer* buffer, const std::string& on) {
          auto message = std::make_unique<Message>();
          std::string why;
          const auto* data = static_cast<const uint8_t*>(buffer->data);
          try {
            const uint32_t tag_bytes = authenticator_ ? kBusTagBytes : 0;
            const uint32_t size = buffer->data_size - std::min(buffer->data_size, tag_bytes);
            int used = -1;
            if (buffer->data_size > max_bytes) {
              why = "is " + std::to_string(buffer->data_size) + " bytes, more than the " + std::to_string(max_bytes) +
                    " a message on this channel may have";
            } else if (authenticator_ && !authenticator_->Verify(on, data, buffer->data_size)) {
              why = "does not carry this bus's tag (forged, or from a sender without the bus key)";
            } else if ((used = message->decode(buffer->data, 0, static_cast<int>(size))) < 0) {
              why = "does not decode as " + std::string(Message::getTypeName()) + " (wrong type or truncated)";
            } else if (static_cast<uint32_t>(used) != size) {
              why = "has " + std::to_string(size - used) + " bytes after the message" +
                    (authenticator_ ? "" : " (a tag: is this bus keyed, bus.key_file?)");
            } else if (message->header.agent != expected_agent) {
              why = "header names agent '" + message->header.agent + "'";
            } else if (replays && !replays->Take(on, message->header.sender_session, message->header.seq)) {
              why = "was taken before (message " + std::to_string(message->header.seq) + " of its sender): a replay";
            }
          } catch (const std::exception& e) {
            why = std::string("could not be decoded: ") + e.what();
          }
          if (!why.empty()) {
            Reject(on, why);
            return;
          }
          handler(std::move(message), on);
        });
    lcm::Subscription* subscription = lcm_->subscribe(channel, &RawHandler::OnMessage, raw.get());
    // LCM drops what arrives while more than this many messages wait for the dispatcher (30 by
    // default, which a burst of submap parts from the link bridge exceeds); handlers only queue.
    subscription->setQueueCapacity(kSubscriptionQueueCapacity);
    subscriptions_.push_back(subscription);
    handlers_.push_back(std::move(raw));
  }

  // Messages dropped as malformed or foreign so far.
  int64_t rejected() const { return rejected_.load(); }
  // Counts a message a handler refuses for its content (a forged or implausible value) like a
  // malformed one, and logs why at most once a second.
  void Reject(const std::string& channel, const std::string& why);

 private:
  struct RawHandler {
    explicit RawHandler(std::function<void(const lcm::ReceiveBuffer*, const std::string&)> f)
        : function(std::move(f)) {}
    void OnMessage(const lcm::ReceiveBuffer* buffer, const std::string& channel) { function(buffer, channel); }
    std::function<void(const lcm::ReceiveBuffer*, const std::string&)> function;
  };

  lcm::LCM* lcm_;
  std::optional<BusAuthenticator> authenticator_;
  std::vector<lcm::Subscription*> subscriptions_;
  std::vector<std::unique_ptr<RawHandler>> handlers_;
  std::atomic<int64_t> rejected_{0};
  std::atomic<int64_t> last_reject_log_us_{0};
};

// Runs LCM's handle loop in its own thread until stopped or destroyed.
class Dispatcher {
 public:
  explicit Dispatcher(lcm::LCM* lcm);
  ~Dispatcher();
  void Start();
  void Stop();

 private:
  lcm::LCM* lcm_;
  std::atomic<bool> running_{false};
  std::thread thread_;
};

}  // namespace stitch::bus
