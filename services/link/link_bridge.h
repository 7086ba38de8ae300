#pragma once
// The link bridge: carries chosen LCM channels between two LCM networks (the aircraft's and the
// ground station's) over plain UDP, which routed radio links carry where multicast does not.
//
// One bridge runs on each side; each sends its `forward` channels to the other and publishes
// what the other sends on its own network, byte for byte. A message is split into numbered
// datagrams; the receiver asks for the ones it lacks (REPAIR) and the sender keeps what it sent
// for `retain_s` to answer, so a lossy link still delivers whole messages. Under a bandwidth
// budget, messages wait in a queue (small ones first, `background` channels begun only when
// nothing else waits, then sent to their end with only small ones between their datagrams) and
// are dropped, oldest first, after `max_queue_s`. A message this bridge published is never sent back
// (no echo between sides).
//
// Threads: LCM's dispatcher (the caller runs it) queues local messages; a sender thread paces
// and transmits; a receiver thread reassembles, asks for repairs and publishes.

#include <netinet/in.h>

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <queue>
#include <regex>
#include <set>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include <lcm/lcm-cpp.hpp>

#include "services/common/bus_auth.h"
#include "services/link/link_auth.h"
#include "services/link/link_wire.h"
#include "stitch/config/link_options.h"
#include "stitch/link_status_t.hpp"
#include "stitch/util/rng.h"
#include "stitch/util/time.h"

namespace stitch {

struct LinkCounts {
  int64_t messages_queued = 0;        // local messages taken for the other side
  int64_t messages_sent = 0;          // every fragment sent at least once
  int64_t messages_expired = 0;       // waited longer than max_queue_s under the budget; dropped
  int64_t messages_refused = 0;       // too large to send
  int64_t local_unauthenticated = 0;  // on this side's keyed bus without its tag: not sent
  int64_t datagrams_sent = 0;         // including repairs, requests and statuses
  int64_t bytes_sent = 0;             // with UDP/IP headers (what the budget counts)
  int64_t datagrams_lost_injected = 0;
  int64_t fragments_repaired = 0;  // sent again because the other side asked
  int64_t repair_requests_sent = 0;
  int64_t messages_delivered = 0;         // from the other side, published here
  int64_t messages_given_up = 0;          // from the other side, never completed
  int64_t datagrams_refused = 0;          // malformed or foreign, unauthenticated and replayed included
  int64_t datagrams_unauthenticated = 0;  // failed authentication (forged, another key, not sealed)
  int64_t datagrams_replayed = 0;         // authentic, but accepted before (or an earlier run's, or this bridge's own)
  int64_t echoes_suppressed = 0;          // our own publications, not sent back
  int64_t queued_bytes = 0;               // waiting now
  double oldest_wait_s = 0;               // how long the oldest waiting message has waited
  double seconds_since_peer = -1;         // since anything came from the other side; -1: never
};

class LinkBridge {
 public:
  // Binds options.listen and resolves options.peer; throws stitch::Error with what to fix.
  // `bus_authenticator`: this side's bus key's (bus.key_file), where its bus has one: only tagged
  // messages are sent, and what comes from the other side is published tagged.
  LinkBridge(lcm::LCM* lcm, LinkOptions options, std::optional<bus::BusAuthenticator> bus_authenticator = std::nullopt);
  ~LinkBridge();
  LinkBridge(const LinkBridge&) = delete;
  LinkBridge& operator=(const LinkBridge&) = delete;

  void Start();
  // Stops the threads (what is still queued is not sent).
  void Stop();

  LinkCounts counts() const;
  // The UDP port bound (useful with port 0 in listen).
  int local_port() const { return local_port_; }
  // Waiting messages and datagrams not yet sent (0: everything queued has left this side).
  size_t backlog() const;
  // Nothing waits to be sent and the other side has asked for no repair for `quiet_s`: what
  // was sent has arrived (a bridge about to stop waits for this).
  bool Settled(double quiet_s) const;
  // The figures as published on <agent>/LINK_STATUS (header left to the publisher).
  // `rate_bytes_per_s`: measured by the caller over its own interval.
  stitch::link_status_t Status(double rate_bytes_per_s) const;
  // One line of figures for the log.
  std::string Describe() const;

 private:
  struct Sending {  // a message whose fragments are going out
    uint64_t message = 0;
    int count = 0;
    int next = 0;
  };
  struct Outgoing {
    std::string channel;
    std::string bytes;
    double queued_at = 0;
  };
  struct Retained {
    std::string channel;
    std::string bytes;
    bool sent = false;  // every fragment has gone out once
    double sent_at = 0;
  };
  struct Delayed {
    double due = 0;
    uint64_t order = 0;
    std::string bytes;
    bool operator>(const Delayed& o) const { return due != o.due ? due > o.due : order > o.order; }
  };
  // A message of the other side, being reassembled (count 0: nothing of it seen yet).
  struct Partial {
    std::string channel;
    std::string bytes;
    std::vector<bool> have;
    int received = 0;
    size_t received_bytes = 0;
    uint16_t count = 0;
    double last_progress = 0;
    int rounds = 0;
  };

  void OnLocalMessage(const lcm::ReceiveBuffer* buffer, const std::string& channel);
  void SendLoop();
  void ReceiveLoop();
  // Sender side, with mutex_ held: the next datagram to send, if any.
  std::optional<std::string> NextDatagramLocked(double now);
  std::string NextFragmentLocked(std::optional<Sending>* sending, double now);
  // Every message below this has been sent whole (what STATUS says).
  uint64_t SentEndLocked() const;
  void Transmit(std::string datagram, double now);
  void SendDue(double now);
  // sendto the peer, waiting briefly while the socket's buffer is full.
  void SendNow(const std::string& datagram);
  void ExpireLocked(double now);
  // Receiver side (receiver thread only).
  void Handle(const link::Datagram& datagram, double now);
  bool AcceptSession(uint64_t session);
  void OnStatus(const link::LinkStatus& status);
  void OnData(const link::DataFragment& fragment, double now);
  void OnRepair(const link::RepairRequest& request);
  void Deliver(uint64_t message, Partial* partial);
  void Finish(uint64_t message);
  void RequestRepairs(double now);
  void QueueControl(std::string datagram);
  static uint64_t EchoKey(const std::string& channel, const uint8_t* data, size_t size);

  lcm::LCM* lcm_;
  const LinkOptions options_;
  const std::optional<bus::BusAuthenticator> bus_authenticator_;
  const uint64_t session_;
  // With a key: what is sent is sealed (sender thread only) and what arrives opened (receiver
  // thread only); fragments leave room for the seal.
  std::optional<link::Sealer> sealer_;
  std::optional<link::Opener> opener_;
  int seal_overhead_ = 0;
  int datagram_bytes_ = 0;  // options_.max_datagram_bytes less the seal
  std::regex accept_;       // options_.accept
  std::regex background_;   // options_.background
  int socket_ = -1;
  int local_port_ = 0;
  sockaddr_in peer_address_{};
  lcm::Subscription* subscription_ = nullptr;

  // Sender state. Lock order: mutex_, then counts_mutex_ (never the other way).
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<Outgoing> small_queue_, large_queue_, background_queue_;
  size_t queued_bytes_ = 0;
  std::deque<std::string> control_;                    // repair requests, statuses: first
  std::deque<std::pair<uint64_t, uint16_t>> repairs_;  // (message, fragment) asked for again
  std::set<std::pair<uint64_t, uint16_t>> repairs_waiting_;
  // A small one goes between a large or a background one's fragments; a background one, once
  // begun, goes before a large one.
  std::optional<Sending> small_sending_, large_sending_, background_sending_;
  uint64_t next_message_ = 0;
  std::map<uint64_t, Retained> retained_;
  size_t retained_bytes_ = 0;
  std::optional<std::string> pending_;  // picked, waiting for budget
  // Token bucket of the budget: a few datagrams, or 50 ms of budget, may go at once.
  const double burst_bytes_ =
      std::max(4.0 * (options_.max_datagram_bytes + link::kUdpIpHeaderBytes), 0.05 * options_.budget_bytes_per_s);
  double tokens_ = 0;
  double tokens_at_ = 0;
  std::priority_queue<Delayed, std::vector<Delayed>, std::greater<>> delay_line_;
  uint64_t delay_order_ = 0;
  Rng impairment_rng_;

  // Receiver state (receiver thread only, except the echo keys).
  uint64_t peer_session_ = 0;
  uint64_t floor_ = 0;        // every message of the peer below this is finished
  bool floor_known_ = false;  // set by the peer's first status
  uint64_t peer_sent_end_ = 0;
  std::map<uint64_t, Partial> incomplete_;
  std::set<uint64_t> finished_;  // finished messages at or above floor_
  size_t incomplete_bytes_ = 0;
  std::mutex echo_mutex_;
  std::unordered_map<uint64_t, double> echo_keys_;  // key -> expiry

  // Warnings at most once per 5 s each.
  class Throttle {
   public:
    bool Allow() {
      const double now = MonotonicSeconds();
      if (now - last_ < 5.0) return false;
      last_ = now;
      return true;
    }

   private:
    double last_ = -1e9;
  };
  Throttle too_large_log_, expired_log_, send_failed_log_, given_up_log_, refused_log_, unauthenticated_log_;

  mutable std::mutex counts_mutex_;  // taken after mutex_ when both are held
  LinkCounts counts_;
  std::atomic<double> last_repair_request_s_{0};
  std::atomic<double> last_heard_s_{-1};
  std::atomic<bool> running_{false};
  std::thread sender_, receiver_;
};

}  // namespace stitch
