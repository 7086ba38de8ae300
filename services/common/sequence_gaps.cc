#include "services/common/sequence_gaps.h"

#include "services/common/big_endian.h"

namespace stitch {

bool SequenceGaps::Observe(const std::string& channel, const void* data, size_t size) {
  ++messages_;
  const auto* bytes = static_cast<const uint8_t*>(data);
  // fingerprint (8), agent: length (4, with its NUL) and bytes, sender_session (8), seq (8).
  constexpr size_t kFingerprint = 8;
  if (size < kFingerprint + 4) {
    ++unreadable_;
    return false;
  }
  const int64_t length = BigEndian(bytes + kFingerprint, 4);
  const size_t agent_at = kFingerprint + 4;
  if (length < 1 || static_cast<uint64_t>(length) > size - agent_at || size - agent_at - length < 16) {
    ++unreadable_;
    return false;
  }
  const std::string agent(reinterpret_cast<const char*>(bytes + agent_at), static_cast<size_t>(length - 1));
  const int64_t session = BigEndian(bytes + agent_at + length, 8);
  const int64_t seq = BigEndian(bytes + agent_at + length + 8, 8);
  const auto [it, first] = last_seq_.try_emplace({channel, agent, session}, seq);
  if (first || seq <= it->second) return true;
  const int64_t gap = seq - it->second - 1;
  it->second = seq;
  if (gap > kMaxGap) {
    ++implausible_;
  } else if (gap > 0) {
    missed_by_channel_[channel] += gap;
  }
  return true;
}

int64_t SequenceGaps::missed() const {
  int64_t total = 0;
  for (const auto& [channel, count] : missed_by_channel_) total += count;
  return total;
}

}  // namespace stitch
