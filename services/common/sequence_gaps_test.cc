// What a recorder missed, from the headers of real stitch messages.

#include "services/common/sequence_gaps.h"

#include <vector>

#include <gtest/gtest.h>

#include "stitch/service_status_t.hpp"

namespace stitch {
namespace {

// A SERVICE message as a sender with `session` publishes it as its `seq`-th on its channel.
std::vector<uint8_t> Encoded(const std::string& agent, int64_t session, int64_t seq) {
  stitch::service_status_t status{};
  status.header.agent = agent;
  status.header.sender_session = session;
  status.header.seq = seq;
  std::vector<uint8_t> bytes(static_cast<size_t>(status.getEncodedSize()));
  EXPECT_EQ(status.encode(bytes.data(), 0, static_cast<int>(bytes.size())), static_cast<int>(bytes.size()));
  return bytes;
}

bool Observe(SequenceGaps* gaps, const std::string& channel, const std::vector<uint8_t>& bytes) {
  return gaps->Observe(channel, bytes.data(), bytes.size());
}

TEST(SequenceGaps, CountsTheMessagesASenderSentBetweenTwoItWasHeardSending) {
  SequenceGaps gaps;
  for (int64_t seq : {4, 5, 8, 9, 12}) EXPECT_TRUE(Observe(&gaps, "uav0/SERVICE", Encoded("uav0", 77, seq)));
  EXPECT_EQ(gaps.missed(), 4) << "6, 7, 10, 11 (what came before 4 was before the recorder listened)";
  // Each sender, session and channel on its own; repeats and reordering miss nothing.
  for (int64_t seq : {0, 2, 2, 1}) Observe(&gaps, "uav1/SERVICE", Encoded("uav1", 77, seq));
  for (int64_t seq : {0, 1}) Observe(&gaps, "uav0/SERVICE", Encoded("uav0", 78, seq));  // uav0 restarted
  EXPECT_EQ(gaps.missed(), 5);
  EXPECT_EQ(gaps.missed_by_channel().at("uav0/SERVICE"), 4);
  EXPECT_EQ(gaps.missed_by_channel().at("uav1/SERVICE"), 1);
  EXPECT_EQ(gaps.messages(), 11);
  EXPECT_EQ(gaps.unreadable(), 0);
}

TEST(SequenceGaps, BytesWithoutAHeaderAndImplausibleJumpsCountNoMessagesMissed) {
  SequenceGaps gaps;
  std::vector<uint8_t> message = Encoded("uav0", 1, 0);
  const size_t header_end = 8 + 4 + 5 + 16;  // fingerprint, "uav0" with its length and NUL, session, seq
  for (size_t cut = 0; cut < header_end; ++cut) {
    EXPECT_FALSE(gaps.Observe("uav0/SERVICE", message.data(), cut)) << cut;
  }
  std::vector<uint8_t> lying = message;
  lying[11] = 0x7f;  // the agent's length, far past the end
  EXPECT_FALSE(Observe(&gaps, "uav0/SERVICE", lying));
  lying[8] = 0x80;  // negative
  EXPECT_FALSE(Observe(&gaps, "uav0/SERVICE", lying));
  EXPECT_TRUE(Observe(&gaps, "uav0/SERVICE", message));
  EXPECT_TRUE(Observe(&gaps, "uav0/SERVICE", Encoded("uav0", 1, int64_t{1} << 62)));
  EXPECT_EQ(gaps.missed(), 0);
  EXPECT_EQ(gaps.implausible(), 1);
  EXPECT_GT(gaps.unreadable(), 20);
}

}  // namespace
}  // namespace stitch
