#pragma once
// Messages authenticated on one side's bus (`bus.key_file`): for an aircraft or a ground station
// whose bus spans several computers on a LAN, where any machine that reaches the multicast group
// could otherwise publish a frame, a keyframe, a status or a backlog that the services believe.
//
// With a key, every message a service publishes carries a 16-byte tag after its LCM encoding:
// keyed BLAKE2b (libsodium's crypto_generichash) of the channel's name and the message's bytes,
// under a key derived from the deployment's (32 random bytes in a 0600 file, `stitch-link keygen`
// makes one). A receiver with the key refuses a message without a valid tag (a forgery, or one
// moved to another channel) and one it has taken before (the sender's session and its sequence
// number on the channel, within a window: a replay). Without a key messages carry no tag, as
// LCM's own tools expect; a receiver without a key refuses a tagged message (bytes after it), so
// every service of one bus must be given the same setting.

#include <array>
#include <cstddef>
#include <cstdint>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <utility>

#include "services/common/replay_window.h"
#include "services/common/secret_file.h"

namespace stitch::bus {

inline constexpr size_t kBusTagBytes = 16;

class BusAuthenticator {
 public:
  // `deployment_key`: the bus key file's secret; the tags' key is derived from it, so a file
  // also used as a link key gives the two unrelated keys.
  explicit BusAuthenticator(const Secret& deployment_key);
  // Reads `path` (stitch::Error saying what is wrong: missing, readable by others, not 64 hex).
  static BusAuthenticator FromFile(const std::string& path);
  // The bus.key_file setting's: none where it is empty.
  static std::optional<BusAuthenticator> FromSetting(const std::string& key_file);

  using Tag = std::array<uint8_t, kBusTagBytes>;
  Tag TagOf(const std::string& channel, const uint8_t* message, size_t size) const;
  // Whether the last kBusTagBytes of `data` are the tag of the bytes before them on `channel`.
  bool Verify(const std::string& channel, const uint8_t* data, size_t size) const;

 private:
  Secret key_;
};

// The (sender's session, sequence number) pairs already taken on each channel: an authenticated
// message heard again is refused. Each sender's channel has its own window (4096 messages behind
// its newest); at most kMaxSenders senders are remembered (the least recently heard is forgotten:
// only authenticated messages add one). Thread-safe.
class ReplayGuard {
 public:
  static constexpr size_t kMaxSenders = 1024;
  // True the first time (channel, session, seq) is seen, within the window.
  bool Take(const std::string& channel, int64_t session, int64_t seq);

 private:
  struct Sender {
    ReplayWindow window;
    uint64_t last_heard = 0;
  };
  std::mutex mutex_;
  std::map<std::pair<std::string, int64_t>, Sender> senders_;
  uint64_t clock_ = 0;
};

}  // namespace stitch::bus
