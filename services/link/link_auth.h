#pragma once
// Authenticated datagrams between the two link bridges. With a key the two sides share (32 random
// bytes per aircraft-ground pair, `stitch link keygen`), every datagram of link_wire.h is sealed
// with XChaCha20-Poly1305 (libsodium's AEAD) before it leaves and opened before anything else
// reads it:
//
//   "STA1" | sender's session (8, little-endian) | counter (8) | ciphertext with its 16-byte tag
//
// Each direction has its own key, derived from the pair's (libsodium's KDF, BLAKE2b): the
// aircraft seals with the aircraft-to-ground key and opens with the other, the ground the other
// way round, so a datagram reflected back to the bridge that sent it fails authentication there.
// The clear 20 bytes are authenticated with the rest; the nonce is the session and the counter,
// so no nonce repeats under one key (each run of a bridge has a new session, its wall-clock
// start in microseconds, and counts from 0). The opener refuses what fails authentication, a
// counter it has already accepted or one that fell out of its window (WireGuard's and IPsec's
// sliding anti-replay window), and a session older than the newest it has accepted (an earlier
// run's datagrams replayed): only an authenticated datagram can make it move to a new session.
// The cost is 36 bytes per datagram (3% of a 1200-byte one).

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "services/common/replay_window.h"
#include "services/common/secret_file.h"

namespace stitch::link {

inline constexpr int kSealOverheadBytes = 4 + 8 + 8 + 16;

using LinkKey = Secret;  // services/common/secret_file.h

// Writes a new random key to `path` (hex, mode 0600); throws stitch::Error when the file exists
// or cannot be written.
void GenerateKeyFile(const std::string& path);
// Reads a key written by GenerateKeyFile; throws stitch::Error saying what is wrong (missing,
// readable by others, not 64 hex digits).
LinkKey LoadKeyFile(const std::string& path);

// The key of the datagrams one side sends ("aircraft" or "ground"), derived from the pair's key.
LinkKey DirectionKey(const LinkKey& pair_key, const std::string& sending_side);
// The side across the link from `side`.
std::string OtherSide(const std::string& side);

class Sealer {
 public:
  Sealer(const LinkKey& key, uint64_t session);
  std::string Seal(const std::string& datagram);

 private:
  LinkKey key_;
  uint64_t session_;
  uint64_t counter_ = 0;
};

class Opener {
 public:
  enum class Verdict { kOpened, kUnauthenticated, kReplayed };
  static constexpr uint64_t kWindow = 4096;  // counters accepted out of order behind the newest

  explicit Opener(const LinkKey& key);
  // Opens a sealed datagram into `datagram`.
  Verdict Open(const uint8_t* bytes, size_t size, std::string* datagram);

 private:
  LinkKey key_;
  uint64_t session_ = 0;            // the newest session accepted
  ReplayWindow counters_{kWindow};  // its counters accepted
};

}  // namespace stitch::link
