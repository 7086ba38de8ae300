// Publishing and subscribing through the bus helpers, in-process (memq) and over UDP multicast.

#include "services/common/bus.h"

#include <unistd.h>

#include <algorithm>
#include <condition_variable>
#include <optional>

#include <gtest/gtest.h>

#include "stitch/frame_ack_t.hpp"
#include "stitch/tracking_status_t.hpp"

namespace stitch::bus {
namespace {

using namespace std::chrono_literals;

// Collects received acks for the test to wait on.
struct Inbox {
  std::mutex mutex;
  std::condition_variable changed;
  std::vector<stitch::frame_ack_t> acks;

  void Add(std::unique_ptr<stitch::frame_ack_t> ack) {
    std::lock_guard<std::mutex> lock(mutex);
    acks.push_back(*ack);
    changed.notify_all();
  }
  bool WaitFor(size_t count, std::chrono::milliseconds timeout) {
    std::unique_lock<std::mutex> lock(mutex);
    return changed.wait_for(lock, timeout, [&] { return acks.size() >= count; });
  }
};

void PublishAndReceive(const std::string& url) {
  auto lcm = OpenLcm(url);
  Inbox inbox;
  Subscriber subscriber(lcm.get());
  subscriber.Subscribe<stitch::frame_ack_t>(
      Channel("uav3", kFrameAck),
      [&](std::unique_ptr<stitch::frame_ack_t> ack, const std::string&) { inbox.Add(std::move(ack)); });
  Dispatcher dispatcher(lcm.get());
  dispatcher.Start();
  Publisher publisher(lcm.get(), "uav3");
  for (int i = 0; i < 3; ++i) {
    stitch::frame_ack_t ack{};
    ack.frame_index = 10 + i;
    publisher.Publish(Channel("uav3", kFrameAck), &ack);
  }
  ASSERT_TRUE(inbox.WaitFor(3, 2000ms)) << "received " << inbox.acks.size() << " of 3 on " << url;
  dispatcher.Stop();
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(inbox.acks[i].frame_index, 10 + i);
    EXPECT_EQ(inbox.acks[i].header.seq, i);
    EXPECT_EQ(inbox.acks[i].header.agent, "uav3");
    EXPECT_EQ(inbox.acks[i].header.sender_session, publisher.session());
    EXPECT_GT(inbox.acks[i].header.utime, 0);
  }
  EXPECT_EQ(subscriber.rejected(), 0);
}

TEST(Bus, PublishesAndReceivesInProcess) {
  PublishAndReceive("memq://");
}

TEST(Bus, PublishesAndReceivesOverUdpMulticast) {
  // A port of this test's own (ttl=0 keeps it on this machine).
  PublishAndReceive(UnusedLocalUdpUrl());
}

TEST(Bus, AnUnusedPortIsNeverOneABusHolds) {
  const int held = UnusedUdpPort();
  const int other = held % 2 == 0 ? held + 1 : held - 1;
  const int first = std::min(held, other);
  auto lcm = OpenLcm(LocalUdpUrl(held));
  // LCM binds its port at the first subscription.
  struct Ignore {
    void Handle(const lcm::ReceiveBuffer*, const std::string&) {}
  } ignore;
  lcm->subscribe("ANY", &Ignore::Handle, &ignore);
  for (int i = 0; i < 50; ++i) EXPECT_EQ(UnusedUdpPort(first, 2), other);
}

TEST(Bus, MalformedAndForeignMessagesNeverReachTheHandler) {
  auto lcm = OpenLcm("memq://");
  Inbox inbox;
  Subscriber subscriber(lcm.get());
  const std::string channel = Channel("uav3", kFrameAck);
  subscriber.Subscribe<stitch::frame_ack_t>(
      channel, [&](std::unique_ptr<stitch::frame_ack_t> ack, const std::string&) { inbox.Add(std::move(ack)); });
  Dispatcher dispatcher(lcm.get());
  dispatcher.Start();

  stitch::frame_ack_t ack{};
  ack.header.agent = "uav3";
  ack.frame_index = 1;
  std::vector<uint8_t> bytes(ack.getEncodedSize());
  ack.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  // Truncated.
  lcm->publish(channel, bytes.data(), static_cast<unsigned>(bytes.size() - 3));
  // Trailing garbage.
  std::vector<uint8_t> longer = bytes;
  longer.push_back(0);
  lcm->publish(channel, longer.data(), static_cast<unsigned>(longer.size()));
  // Another type on this channel.
  stitch::tracking_status_t status{};
  status.header.agent = "uav3";
  lcm->publish(channel, &status);
  // Random bytes.
  std::vector<uint8_t> noise(64, 0xAB);
  lcm->publish(channel, noise.data(), static_cast<unsigned>(noise.size()));
  // Another agent's message on our channel.
  stitch::frame_ack_t foreign = ack;
  foreign.header.agent = "intruder";
  lcm->publish(channel, &foreign);
  // More than any message may be: refused undecoded.
  std::vector<uint8_t> huge(kMaxMessageBytes + 1, 0);
  std::copy(bytes.begin(), bytes.end(), huge.begin());
  lcm->publish(channel, huge.data(), static_cast<unsigned>(huge.size()));
  // Finally a good one, which must arrive.
  lcm->publish(channel, &ack);

  ASSERT_TRUE(inbox.WaitFor(1, 2000ms));
  std::this_thread::sleep_for(100ms);
  dispatcher.Stop();
  EXPECT_EQ(inbox.acks.size(), 1u);
  EXPECT_EQ(subscriber.rejected(), 6);
}

// Every tool that opens a multicast bus asks for a receive buffer that holds a flight's traffic
// (the docs' address form named none: a recorder lost submap messages); one the user names stays.
// A bus key (bus.key_file): what a process without it publishes, a tag under another key, a tag
// moved to another channel and a message heard again are refused; the keyed sender's arrive.
TEST(Bus, OnAKeyedBusOnlyTaggedMessagesHeardOnceReachTheHandler) {
  auto lcm = OpenLcm("memq://");
  const BusAuthenticator authenticator(RandomSecret());
  Inbox inbox;
  Subscriber subscriber(lcm.get(), authenticator);
  const std::string channel = Channel("uav3", kFrameAck);
  subscriber.Subscribe<stitch::frame_ack_t>(
      channel, [&](std::unique_ptr<stitch::frame_ack_t> ack, const std::string&) { inbox.Add(std::move(ack)); });
  // What the keyed sender put on the bus, as a listener on the network hears it.
  struct Recorder {
    std::mutex mutex;
    std::vector<std::vector<uint8_t>> heard;
    void Handle(const lcm::ReceiveBuffer* buffer, const std::string&) {
      const auto* data = static_cast<const uint8_t*>(buffer->data);
      std::lock_guard<std::mutex> lock(mutex);
      heard.emplace_back(data, data + buffer->data_size);
    }
    std::optional<std::vector<uint8_t>> First() {
      std::lock_guard<std::mutex> lock(mutex);
      return heard.empty() ? std::nullopt : std::optional<std::vector<uint8_t>>(heard.front());
    }
  } recorder;
  lcm::Subscription* recording = lcm->subscribe(channel, &Recorder::Handle, &recorder);
  Dispatcher dispatcher(lcm.get());
  dispatcher.Start();

  Publisher keyed(lcm.get(), "uav3", authenticator);
  Publisher forger(lcm.get(), "uav3");                                       // no key
  Publisher other_key(lcm.get(), "uav3", BusAuthenticator(RandomSecret()));  // another deployment's
  stitch::frame_ack_t ack{};
  ack.frame_index = 1;
  keyed.Publish(channel, &ack);
  ASSERT_TRUE(inbox.WaitFor(1, 2000ms));
  ack.frame_index = 666;
  forger.Publish(channel, &ack);
  other_key.Publish(channel, &ack);
  // The keyed sender's message, replayed as it was heard (the recorder hears it after the
  // subscriber: wait for it).
  for (int i = 0; i < 100 && !recorder.First(); ++i) std::this_thread::sleep_for(10ms);
  ASSERT_TRUE(recorder.First());
  const std::vector<uint8_t> replay = *recorder.First();
  lcm->publish(channel, replay.data(), static_cast<unsigned>(replay.size()));
  ack.frame_index = 2;
  keyed.Publish(channel, &ack);
  ASSERT_TRUE(inbox.WaitFor(2, 2000ms));
  std::this_thread::sleep_for(100ms);
  dispatcher.Stop();
  lcm->unsubscribe(recording);

  ASSERT_EQ(inbox.acks.size(), 2u);
  EXPECT_EQ(inbox.acks[0].frame_index, 1);
  EXPECT_EQ(inbox.acks[1].frame_index, 2);
  EXPECT_EQ(subscriber.rejected(), 3);
  // The tag binds the channel: the same bytes on another channel do not check out.
  EXPECT_TRUE(authenticator.Verify(channel, replay.data(), replay.size()));
  EXPECT_FALSE(authenticator.Verify(Channel("uav3", kFrame), replay.data(), replay.size()));
  // A service left without the key refuses tagged messages rather than misreading them.
  Subscriber unkeyed(lcm.get());
  Inbox unkeyed_inbox;
  unkeyed.Subscribe<stitch::frame_ack_t>(
      channel, [&](std::unique_ptr<stitch::frame_ack_t> a, const std::string&) { unkeyed_inbox.Add(std::move(a)); });
  Dispatcher second(lcm.get());
  second.Start();
  keyed.Publish(channel, &ack);
  for (int i = 0; i < 500 && unkeyed.rejected() < 1; ++i) std::this_thread::sleep_for(10ms);
  second.Stop();
  EXPECT_TRUE(unkeyed_inbox.acks.empty());
  EXPECT_EQ(unkeyed.rejected(), 1);
}

// A status is a few hundred bytes: one of 2 MB is refused before it is decoded (decoding a forged
// 32 MB status cost about 100 MB), one of 512 kB still passes.
TEST(Bus, EachChannelHasItsOwnLargestMessage) {
  EXPECT_EQ(MaxMessageBytes(Channel("uav0", kFrame)), kMaxMessageBytes);
  EXPECT_EQ(MaxMessageBytes(Channel("uav0", kSubmap)), kMaxMessageBytes);
  EXPECT_EQ(MaxMessageBytes(Channel("uav0", kKeyframeImage)), 9u << 20);
  EXPECT_EQ(MaxMessageBytes(Channel("uav0", kTrackingStatus)), 1u << 20);
  EXPECT_EQ(MaxMessageBytes(Channel("station", kLinkStatus)), 1u << 20);
  auto lcm = OpenLcm("memq://");
  Subscriber subscriber(lcm.get());
  std::atomic<int> taken{0};
  const std::string channel = Channel("uav3", kTrackingStatus);
  subscriber.Subscribe<stitch::tracking_status_t>(
      channel, [&](std::unique_ptr<stitch::tracking_status_t>, const std::string&) { ++taken; });
  Dispatcher dispatcher(lcm.get());
  dispatcher.Start();
  Publisher publisher(lcm.get(), "uav3");
  stitch::tracking_status_t status{};
  status.detail = std::string(2 << 20, 'x');
  publisher.Publish(channel, &status);
  status.detail = std::string(512 << 10, 'x');
  publisher.Publish(channel, &status);
  for (int i = 0; i < 100 && taken.load() + subscriber.rejected() < 2; ++i) std::this_thread::sleep_for(20ms);
  dispatcher.Stop();
  EXPECT_EQ(taken.load(), 1);
  EXPECT_EQ(subscriber.rejected(), 1);
}

TEST(ReplayGuard, TakesEachSendersMessageOnceAndNothingBehindItsWindow) {
  ReplayGuard guard;
  EXPECT_TRUE(guard.Take("uav0/FRAME", 7, 0));
  EXPECT_TRUE(guard.Take("uav0/FRAME", 7, 5));
  EXPECT_TRUE(guard.Take("uav0/FRAME", 7, 3));  // late, but not seen
  EXPECT_FALSE(guard.Take("uav0/FRAME", 7, 3));
  EXPECT_FALSE(guard.Take("uav0/FRAME", 7, 5));
  EXPECT_TRUE(guard.Take("uav0/FRAME", 8, 5));  // another sender (a restart)
  EXPECT_TRUE(guard.Take("uav0/POSE", 7, 5));   // another channel
  EXPECT_TRUE(guard.Take("uav0/FRAME", 7, 10000));
  EXPECT_FALSE(guard.Take("uav0/FRAME", 7, 4));  // fell behind the window
  EXPECT_FALSE(guard.Take("uav0/FRAME", 7, -1));
}

TEST(Bus, AMulticastAddressWithoutAReceiveBufferGetsOne) {
  EXPECT_EQ(WithReceiveBuffer("udpm://239.255.76.67:7746?ttl=0"),
            "udpm://239.255.76.67:7746?ttl=0&recv_buf_size=2097152");
  EXPECT_EQ(WithReceiveBuffer("udpm://239.255.76.67:7746"), "udpm://239.255.76.67:7746?recv_buf_size=2097152");
  EXPECT_EQ(WithReceiveBuffer("udpm://239.255.76.67:7746?ttl=0&recv_buf_size=8388608"),
            "udpm://239.255.76.67:7746?ttl=0&recv_buf_size=8388608");
  EXPECT_EQ(WithReceiveBuffer("memq://"), "memq://");
  EXPECT_EQ(DefaultLcmUrl(), "udpm://239.255.76.67:7667?ttl=0&recv_buf_size=2097152");
}

TEST(Bus, AgentNamesAreChecked) {
  EXPECT_EQ(Channel("uav0", kFrame), "uav0/FRAME");
  EXPECT_THROW(Channel("uav 0", kFrame), Error);
  EXPECT_THROW(Channel("", kFrame), Error);
  EXPECT_THROW(Channel("a.*", kFrame), Error);
}

}  // namespace
}  // namespace stitch::bus
