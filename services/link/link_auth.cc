#include "services/link/link_auth.h"

#include <sodium.h>

#include <cstring>

#include "services/common/secret_file.h"
#include "stitch/util/error.h"

namespace stitch::link {
namespace {

constexpr uint8_t kSealMagic[4] = {'S', 'T', 'A', '1'};
constexpr size_t kClearBytes = 4 + 8 + 8;

void InitSodium() {
  if (sodium_init() < 0) throw Error("libsodium cannot be initialized");
}

void PutLittleEndian(uint64_t value, uint8_t* out) {
  for (int i = 0; i < 8; ++i) out[i] = static_cast<uint8_t>(value >> (8 * i));
}

uint64_t GetLittleEndian(const uint8_t* in) {
  uint64_t value = 0;
  for (int i = 7; i >= 0; --i) value = (value << 8) | in[i];
  return value;
}

// The nonce of (session, counter): unique under one key while sessions are.
void MakeNonce(uint64_t session, uint64_t counter, uint8_t* nonce) {
  std::memset(nonce, 0, crypto_aead_xchacha20poly1305_ietf_NPUBBYTES);
  PutLittleEndian(session, nonce);
  PutLittleEndian(counter, nonce + 8);
}

}  // namespace

void GenerateKeyFile(const std::string& path) {
  GenerateSecretFile(path, "link key");
}

LinkKey LoadKeyFile(const std::string& path) {
  return LoadSecretFile(path, "link key", "make one with `stitch link keygen`");
}

LinkKey DirectionKey(const LinkKey& pair_key, const std::string& sending_side) {
  InitSodium();
  if (sending_side != "aircraft" && sending_side != "ground") {
    throw Error("link side '" + sending_side + "': expected aircraft or ground");
  }
  static_assert(crypto_kdf_KEYBYTES == sizeof(LinkKey) && crypto_kdf_CONTEXTBYTES == 8);
  LinkKey key;
  crypto_kdf_derive_from_key(key.data(), key.size(), sending_side == "aircraft" ? 1 : 2, "stitchdn", pair_key.data());
  return key;
}

std::string OtherSide(const std::string& side) {
  return side == "aircraft" ? "ground" : "aircraft";
}

Sealer::Sealer(const LinkKey& key, uint64_t session) : key_(key), session_(session) {
  InitSodium();
}

std::string Sealer::Seal(const std::string& datagram) {
  std::string sealed(kClearBytes + datagram.size() + crypto_aead_xchacha20poly1305_ietf_ABYTES, '\0');
  auto* out = reinterpret_cast<uint8_t*>(sealed.data());
  std::memcpy(out, kSealMagic, 4);
  PutLittleEndian(session_, out + 4);
  PutLittleEndian(counter_, out + 12);
  uint8_t nonce[crypto_aead_xchacha20poly1305_ietf_NPUBBYTES];
  MakeNonce(session_, counter_, nonce);
  ++counter_;
  unsigned long long length = 0;
  crypto_aead_xchacha20poly1305_ietf_encrypt(out + kClearBytes, &length,
                                             reinterpret_cast<const uint8_t*>(datagram.data()), datagram.size(), out,
                                             kClearBytes, nullptr, nonce, key_.data());
  return sealed;
}

Opener::Opener(const LinkKey& key) : key_(key) {
  InitSodium();
}

Opener::Verdict Opener::Open(const uint8_t* bytes, size_t size, std::string* datagram) {
  if (size < static_cast<size_t>(kSealOverheadBytes) || std::memcmp(bytes, kSealMagic, 4) != 0) {
    return Verdict::kUnauthenticated;
  }
  const uint64_t session = GetLittleEndian(bytes + 4), counter = GetLittleEndian(bytes + 12);
  uint8_t nonce[crypto_aead_xchacha20poly1305_ietf_NPUBBYTES];
  MakeNonce(session, counter, nonce);
  std::string plain(size - kClearBytes - crypto_aead_xchacha20poly1305_ietf_ABYTES, '\0');
  unsigned long long length = 0;
  if (crypto_aead_xchacha20poly1305_ietf_decrypt(reinterpret_cast<uint8_t*>(plain.data()), &length, nullptr,
                                                 bytes + kClearBytes, size - kClearBytes, bytes, kClearBytes, nonce,
                                                 key_.data()) != 0) {
    return Verdict::kUnauthenticated;
  }
  // Authentic: now the session and the counter can be believed.
  if (session < session_) return Verdict::kReplayed;  // an earlier run of the other side
  if (session > session_) {
    session_ = session;
    counters_.Reset();
  }
  if (!counters_.Take(counter)) return Verdict::kReplayed;
  plain.resize(length);
  *datagram = std::move(plain);
  return Verdict::kOpened;
}

}  // namespace stitch::link
