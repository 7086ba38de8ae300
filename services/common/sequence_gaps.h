#pragma once
// What a listener missed on the bus, from the header every stitch message starts with (header_t:
// the sender's agent and session, and its sequence number per channel, +1 for each message). A
// recorder counts it to say what its recording lacks (`stitch record`).

#include <cstddef>
#include <cstdint>
#include <map>
#include <string>
#include <tuple>

namespace stitch {

class SequenceGaps {
 public:
  // Reads the message's header without decoding the rest (the type's 8-byte fingerprint, then
  // header_t's agent, session and seq). False, and counted as unreadable, for bytes that hold no
  // such header (too short, a string running past the end). A sender's first message seen, a
  // new session (a restart) and a message at or before the last one seen (repeated, reordered)
  // count nothing; a jump of more than kMaxGap is counted as implausible, not as messages missed.
  bool Observe(const std::string& channel, const void* data, size_t size);

  static constexpr int64_t kMaxGap = 1'000'000;

  int64_t messages() const { return messages_; }
  int64_t missed() const;
  const std::map<std::string, int64_t>& missed_by_channel() const { return missed_by_channel_; }
  int64_t unreadable() const { return unreadable_; }
  int64_t implausible() const { return implausible_; }

 private:
  // (channel, agent, session) -> the highest seq seen.
  std::map<std::tuple<std::string, std::string, int64_t>, int64_t> last_seq_;
  std::map<std::string, int64_t> missed_by_channel_;
  int64_t messages_ = 0, unreadable_ = 0, implausible_ = 0;
};

}  // namespace stitch
