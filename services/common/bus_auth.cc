#include "services/common/bus_auth.h"

#include <sodium.h>

#include <algorithm>

#include "stitch/util/error.h"

namespace stitch::bus {

BusAuthenticator::BusAuthenticator(const Secret& deployment_key) {
  if (sodium_init() < 0) throw Error("libsodium cannot be initialized");
  static_assert(crypto_kdf_KEYBYTES == sizeof(Secret) && crypto_kdf_CONTEXTBYTES == 8);
  crypto_kdf_derive_from_key(key_.data(), key_.size(), 1, "stitchbs", deployment_key.data());
}

BusAuthenticator BusAuthenticator::FromFile(const std::string& path) {
  return BusAuthenticator(
      LoadSecretFile(path, "bus key", "make one with `stitch-link keygen FILE` and give it to every service"));
}

std::optional<BusAuthenticator> BusAuthenticator::FromSetting(const std::string& key_file) {
  if (key_file.empty()) return std::nullopt;
  return FromFile(key_file);
}

BusAuthenticator::Tag BusAuthenticator::TagOf(const std::string& channel, const uint8_t* message, size_t size) const {
  crypto_generichash_state state;
  crypto_generichash_init(&state, key_.data(), key_.size(), kBusTagBytes);
  // The channel's length first: no channel and message can be cut elsewhere into another pair.
  const uint32_t length = static_cast<uint32_t>(channel.size());
  const uint8_t length_bytes[4] = {static_cast<uint8_t>(length), static_cast<uint8_t>(length >> 8),
                                   static_cast<uint8_t>(length >> 16), static_cast<uint8_t>(length >> 24)};
  crypto_generichash_update(&state, length_bytes, sizeof(length_bytes));
  crypto_generichash_update(&state, reinterpret_cast<const uint8_t*>(channel.data()), channel.size());
  crypto_generichash_update(&state, message, size);
  Tag tag;
  crypto_generichash_final(&state, tag.data(), tag.size());
  return tag;
}

bool BusAuthenticator::Verify(const std::string& channel, const uint8_t* data, size_t size) const {
  if (size < kBusTagBytes) return false;
  const Tag expected = TagOf(channel, data, size - kBusTagBytes);
  return sodium_memcmp(expected.data(), data + size - kBusTagBytes, kBusTagBytes) == 0;
}

bool ReplayGuard::Take(const std::string& channel, int64_t session, int64_t seq) {
  if (seq < 0) return false;
  std::lock_guard<std::mutex> lock(mutex_);
  auto key = std::make_pair(channel, session);
  auto found = senders_.find(key);
  if (found == senders_.end()) {
    if (senders_.size() >= kMaxSenders) {
      senders_.erase(std::min_element(senders_.begin(), senders_.end(), [](const auto& a, const auto& b) {
        return a.second.last_heard < b.second.last_heard;
      }));
    }
    found = senders_.emplace(std::move(key), Sender{}).first;
  }
  found->second.last_heard = ++clock_;
  return found->second.window.Take(static_cast<uint64_t>(seq));
}

}  // namespace stitch::bus
