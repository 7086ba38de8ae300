// The link bridge: its datagrams, and two bridges between two buses over loopback UDP, with
// loss, delay, reordering, a budget and garbage on the port.

#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <map>
#include <mutex>
#include <set>
#include <thread>

#include <gtest/gtest.h>

#include "services/common/bus.h"
#include "services/link/link_auth.h"
#include "services/link/link_bridge.h"
#include "services/link/link_wire.h"
#include "stitch/frame_ack_t.hpp"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/rng.h"
#include "stitch/util/time.h"

namespace stitch {
namespace {

using namespace std::chrono_literals;

std::string RandomBytes(size_t size, uint64_t seed) {
  Rng rng(seed);
  std::string bytes(size, '\0');
  for (char& c : bytes) c = static_cast<char>(rng.NextU64() & 0xff);
  return bytes;
}

bool DecodeString(const std::string& bytes, link::Datagram* out, std::string* why = nullptr) {
  return link::Decode(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size(), out, why);
}

TEST(LinkWire, FragmentsReassembleIntoTheMessageAndFitTheDatagramSize) {
  for (size_t size : {size_t{0}, size_t{1}, size_t{1100}, size_t{1150}, size_t{100000}}) {
    const std::string message = RandomBytes(size, size + 1);
    const auto fragments = link::Fragment(7, 42, "uav0/SUBMAP", message, 1200);
    ASSERT_FALSE(fragments.empty());
    EXPECT_EQ(static_cast<int>(fragments.size()), link::FragmentCount("uav0/SUBMAP", size, 1200));
    std::string rebuilt(size, '\0');
    for (const auto& fragment : fragments) {
      const std::string datagram = link::Encode(fragment);
      EXPECT_LE(datagram.size(), 1200u);
      link::Datagram decoded;
      std::string why;
      ASSERT_TRUE(DecodeString(datagram, &decoded, &why)) << why;
      ASSERT_EQ(decoded.type, link::DatagramType::kData);
      EXPECT_EQ(decoded.data.session, 7u);
      EXPECT_EQ(decoded.data.message, 42u);
      EXPECT_EQ(decoded.data.channel, "uav0/SUBMAP");
      EXPECT_EQ(decoded.data.count, fragments.size());
      rebuilt.replace(decoded.data.offset, decoded.data.payload.size(), decoded.data.payload);
    }
    EXPECT_EQ(rebuilt, message) << size;
  }
  EXPECT_TRUE(link::Fragment(1, 1, std::string(300, 'c'), "x", 1200).empty());  // channel too long
  EXPECT_EQ(link::FragmentCount("c", 20000000, 256), 0);                        // would need more than 65535 fragments
}

TEST(LinkWire, RepairRequestsAndStatusesRoundTripAndSplitToFit) {
  link::RepairRequest request{99, {}};
  for (uint64_t m = 0; m < 40; ++m) {
    link::RepairRequest::Wanted wanted{1000 + m, {}};
    if (m % 3) {
      for (uint16_t i = 0; i < 30 * m; i += 2) wanted.missing.push_back(i);
    }
    request.wanted.push_back(wanted);
  }
  const auto parts = link::SplitRepair(request, 300);
  EXPECT_GT(parts.size(), 5u);
  std::map<uint64_t, std::vector<uint16_t>> got;
  std::map<uint64_t, int> named;
  for (const auto& part : parts) {
    const std::string datagram = link::Encode(part);
    EXPECT_LE(datagram.size(), 300u);
    link::Datagram decoded;
    ASSERT_TRUE(DecodeString(datagram, &decoded));
    ASSERT_EQ(decoded.type, link::DatagramType::kRepair);
    EXPECT_EQ(decoded.repair.session, 99u);
    for (const auto& wanted : decoded.repair.wanted) {
      ++named[wanted.message];
      auto& list = got[wanted.message];
      list.insert(list.end(), wanted.missing.begin(), wanted.missing.end());
    }
  }
  for (const auto& wanted : request.wanted) {
    EXPECT_EQ(got[wanted.message], wanted.missing) << wanted.message;
    EXPECT_GE(named[wanted.message], 1);
  }
  link::Datagram status;
  ASSERT_TRUE(DecodeString(link::Encode(link::LinkStatus{5, 10, 3}), &status));
  EXPECT_EQ(status.type, link::DatagramType::kStatus);
  EXPECT_EQ(status.status.sent_end, 10u);
  EXPECT_EQ(status.status.retained_begin, 3u);
}

TEST(LinkWire, EveryTruncationAndCorruptionIsRefusedWithAReason) {
  std::vector<std::string> good = {
      link::Encode(link::Fragment(1, 2, "uav0/SUBMAP", RandomBytes(3000, 3), 1200)[1]),
      link::Encode(link::RepairRequest{1, {{5, {1, 2, 3}}, {6, {}}}}),
      link::Encode(link::LinkStatus{1, 9, 2}),
  };
  for (const std::string& datagram : good) {
    for (size_t cut = 0; cut < datagram.size(); ++cut) {
      link::Datagram decoded;
      std::string why;
      const std::string truncated = datagram.substr(0, cut);
      // A data fragment cut inside its payload is a shorter fragment (the receiver checks the
      // whole message); anything cut inside a header must be refused.
      if (DecodeString(truncated, &decoded, &why)) {
        EXPECT_EQ(decoded.type, link::DatagramType::kData) << cut;
      } else {
        EXPECT_FALSE(why.empty());
      }
    }
  }
  Rng rng(5);
  int refused = 0;
  for (int trial = 0; trial < 20000; ++trial) {
    std::string datagram = good[trial % good.size()];
    const int flips = 1 + trial % 4;
    for (int f = 0; f < flips; ++f)
      datagram[rng.UniformInt(0, static_cast<int>(datagram.size()) - 1)] ^= 1 << rng.UniformInt(0, 7);
    link::Datagram decoded;
    std::string why;
    if (!DecodeString(datagram, &decoded, &why)) {
      ++refused;
      EXPECT_FALSE(why.empty());
    } else if (decoded.type == link::DatagramType::kData) {
      EXPECT_LT(decoded.data.index, decoded.data.count);
      EXPECT_LE(decoded.data.offset + decoded.data.payload.size(), decoded.data.message_bytes);
    }
  }
  EXPECT_GT(refused, 1000);
  link::Datagram decoded;
  std::string why;
  EXPECT_FALSE(DecodeString("STL1", &decoded, &why));
  EXPECT_FALSE(DecodeString(std::string("XXXX\x01\x01") + std::string(40, '\0'), &decoded, &why));
  EXPECT_NE(why.find("magic"), std::string::npos) << why;
}

// A port free on loopback now (a test may race another process for it; unlikely).
int FreeUdpPort() {
  const int s = socket(AF_INET, SOCK_DGRAM, 0);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  bind(s, reinterpret_cast<sockaddr*>(&address), sizeof(address));
  socklen_t length = sizeof(address);
  getsockname(s, reinterpret_cast<sockaddr*>(&address), &length);
  close(s);
  return ntohs(address.sin_port);
}

// Everything published on a bus, by channel, in arrival order.
class Collector {
 public:
  Collector(lcm::LCM* lcm, const std::string& channels) : lcm_(lcm) {
    subscription_ = lcm_->subscribe(channels, &Collector::On, this);
    subscription_->setQueueCapacity(bus::kSubscriptionQueueCapacity);
  }
  ~Collector() { lcm_->unsubscribe(subscription_); }
  std::vector<std::string> Get(const std::string& channel) const {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = received_.find(channel);
    return it == received_.end() ? std::vector<std::string>() : it->second;
  }
  std::vector<std::string> order() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return order_;
  }
  // Waits until `channel` has `count` messages or `timeout` passes.
  bool WaitFor(const std::string& channel, size_t count, std::chrono::milliseconds timeout) const {
    const auto end = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < end) {
      if (Get(channel).size() >= count) return true;
      std::this_thread::sleep_for(10ms);
    }
    return Get(channel).size() >= count;
  }

 private:
  void On(const lcm::ReceiveBuffer* buffer, const std::string& channel) {
    std::lock_guard<std::mutex> lock(mutex_);
    received_[channel].emplace_back(static_cast<const char*>(buffer->data), buffer->data_size);
    order_.push_back(channel);
  }
  lcm::LCM* lcm_;
  lcm::Subscription* subscription_;
  mutable std::mutex mutex_;
  std::map<std::string, std::vector<std::string>> received_;
  std::vector<std::string> order_;
};

// Two buses (the aircraft's and the ground's), a bridge on each, joined over loopback.
struct TwoSides {
  // Authenticated as deployed: both sides share a new key, unless the options name one or say insecure.
  // `aircraft_bus_key`, `ground_bus_key`: each side's bus key (bus.key_file), where it has one.
  explicit TwoSides(LinkOptions aircraft_options = {}, LinkOptions ground_options = {},
                    std::optional<bus::BusAuthenticator> aircraft_bus_key = {},
                    std::optional<bus::BusAuthenticator> ground_bus_key = {}) {
    key_file = (key_dir.path() / "link.key").string();
    link::GenerateKeyFile(key_file);
    for (LinkOptions* o : {&aircraft_options, &ground_options}) {
      if (o->key_file.empty() && !o->insecure) o->key_file = key_file;
    }
    if (aircraft_options.side.empty()) aircraft_options.side = "aircraft";
    if (ground_options.side.empty()) ground_options.side = "ground";
    aircraft_port = FreeUdpPort();
    const int ground_port = FreeUdpPort();
    if (aircraft_options.forward == LinkOptions().forward) aircraft_options.forward = "uav0/(SUBMAP|SEQUENCE)";
    aircraft_options.listen = "127.0.0.1:" + std::to_string(aircraft_port);
    aircraft_options.peer = "127.0.0.1:" + std::to_string(ground_port);
    aircraft_options.report_interval_s = 0;
    if (ground_options.forward == LinkOptions().forward) {
      ground_options.forward = "uav0/(SUBMAP_REQUEST|SEQUENCE)";  // SEQUENCE both ways: no echo allowed
    }
    ground_options.listen = "127.0.0.1:" + std::to_string(ground_port);
    ground_options.peer = "127.0.0.1:" + std::to_string(aircraft_port);
    ground_options.report_interval_s = 0;
    ground_options.seed = aircraft_options.seed + 100;
    aircraft_bus = bus::OpenLcm("memq://");
    ground_bus = bus::OpenLcm("memq://");
    aircraft_seen = std::make_unique<Collector>(aircraft_bus.get(), "uav0/.*");
    ground_seen = std::make_unique<Collector>(ground_bus.get(), "uav0/.*");
    aircraft = std::make_unique<LinkBridge>(aircraft_bus.get(), aircraft_options, aircraft_bus_key);
    ground = std::make_unique<LinkBridge>(ground_bus.get(), ground_options, ground_bus_key);
    ground_settings = ground_options;
    aircraft_settings = aircraft_options;
    aircraft_dispatcher = std::make_unique<bus::Dispatcher>(aircraft_bus.get());
    ground_dispatcher = std::make_unique<bus::Dispatcher>(ground_bus.get());
    aircraft_dispatcher->Start();
    ground_dispatcher->Start();
    aircraft->Start();
    ground->Start();
  }
  ~TwoSides() {
    aircraft_dispatcher->Stop();
    ground_dispatcher->Stop();
    aircraft.reset();
    ground.reset();
  }
  // The ground's bridge goes down (nothing listens on its port meanwhile) and comes back.
  void StopGround() {
    ground_dispatcher->Stop();
    ground.reset();
  }
  void StartGround() {
    ground = std::make_unique<LinkBridge>(ground_bus.get(), ground_settings);
    ground_dispatcher->Start();
    ground->Start();
  }
  void StopAircraft() {
    aircraft_dispatcher->Stop();
    aircraft.reset();
  }
  void StartAircraft() {
    aircraft = std::make_unique<LinkBridge>(aircraft_bus.get(), aircraft_settings);
    aircraft_dispatcher->Start();
    aircraft->Start();
  }
  testing::TempDir key_dir;
  std::string key_file;
  int aircraft_port = 0;
  LinkOptions ground_settings, aircraft_settings;
  std::unique_ptr<lcm::LCM> aircraft_bus, ground_bus;
  std::unique_ptr<Collector> aircraft_seen, ground_seen;
  std::unique_ptr<LinkBridge> aircraft, ground;
  std::unique_ptr<bus::Dispatcher> aircraft_dispatcher, ground_dispatcher;
};

void Publish(lcm::LCM* lcm, const std::string& channel, const std::string& bytes) {
  lcm->publish(channel, bytes.data(), static_cast<unsigned int>(bytes.size()));
}

TEST(LinkBridge, CarriesTheChosenChannelsBothWaysByteForByteWithoutEcho) {
  TwoSides sides;
  const std::vector<size_t> sizes = {0, 10, 1150, 5000, 300000};
  for (size_t i = 0; i < sizes.size(); ++i) Publish(sides.aircraft_bus.get(), "uav0/SUBMAP", RandomBytes(sizes[i], i));
  Publish(sides.aircraft_bus.get(), "uav0/FRAME", RandomBytes(5000, 9));  // not forwarded
  Publish(sides.ground_bus.get(), "uav0/SUBMAP_REQUEST", "ask");
  Publish(sides.aircraft_bus.get(), "uav0/SEQUENCE", "sequence");  // forwarded both ways
  ASSERT_TRUE(sides.ground_seen->WaitFor("uav0/SUBMAP", sizes.size(), 5s));
  ASSERT_TRUE(sides.aircraft_seen->WaitFor("uav0/SUBMAP_REQUEST", 1, 5s));
  ASSERT_TRUE(sides.ground_seen->WaitFor("uav0/SEQUENCE", 1, 5s));
  std::this_thread::sleep_for(500ms);
  const auto got = sides.ground_seen->Get("uav0/SUBMAP");
  ASSERT_EQ(got.size(), sizes.size());
  for (size_t i = 0; i < sizes.size(); ++i) EXPECT_EQ(got[i], RandomBytes(sizes[i], i)) << i;
  EXPECT_TRUE(sides.ground_seen->Get("uav0/FRAME").empty());
  EXPECT_EQ(sides.aircraft_seen->Get("uav0/SUBMAP_REQUEST"), std::vector<std::string>{"ask"});
  // SEQUENCE crossed once and did not come back: the aircraft saw its own publication only.
  EXPECT_EQ(sides.ground_seen->Get("uav0/SEQUENCE").size(), 1u);
  EXPECT_EQ(sides.aircraft_seen->Get("uav0/SEQUENCE").size(), 1u);
  EXPECT_EQ(sides.ground->counts().echoes_suppressed, 1);
  EXPECT_EQ(sides.aircraft->counts().messages_given_up + sides.ground->counts().messages_given_up, 0);
}

TEST(LinkBridge, RepairsWhatAFifthLossEachWayAndJitterDoToEveryMessage) {
  LinkOptions aircraft, ground;
  for (LinkOptions* o : {&aircraft, &ground}) {
    o->loss = 0.2;
    o->delay_ms = 30;
    o->jitter_ms = 20;  // reorders datagrams
    o->repair_after_ms = 120;
  }
  aircraft.seed = 3;
  TwoSides sides(aircraft, ground);
  const int kMessages = 120;
  for (int i = 0; i < kMessages; ++i) {
    Publish(sides.aircraft_bus.get(), "uav0/SUBMAP", RandomBytes(i % 4 == 0 ? 40000 : 700, 1000 + i));
  }
  EXPECT_TRUE(sides.ground_seen->WaitFor("uav0/SUBMAP", kMessages, 30s));
  std::this_thread::sleep_for(300ms);
  std::printf("down: %s\nup: %s\n", sides.aircraft->Describe().c_str(), sides.ground->Describe().c_str());
  const auto got = sides.ground_seen->Get("uav0/SUBMAP");
  ASSERT_EQ(got.size(), static_cast<size_t>(kMessages));  // each once
  std::set<std::string> expected, received(got.begin(), got.end());
  for (int i = 0; i < kMessages; ++i) expected.insert(RandomBytes(i % 4 == 0 ? 40000 : 700, 1000 + i));
  EXPECT_EQ(received, expected);
  const LinkCounts down = sides.aircraft->counts(), up = sides.ground->counts();
  EXPECT_GT(down.datagrams_lost_injected, 100);
  EXPECT_GT(down.fragments_repaired, 100);
  // One request names every fragment missing at the time: fewer, larger requests when the
  // bridge's thread runs late (9 in an ASan run beside a TSan run; 10+ on an idle machine).
  EXPECT_GT(up.repair_requests_sent, 3);
  EXPECT_EQ(up.messages_given_up, 0);
  EXPECT_EQ(up.messages_delivered, kMessages);
}

TEST(LinkBridge, AGroundBridgeThatWasDownReceivesWhatTheAircraftStillKeeps) {
  TwoSides sides;
  Publish(sides.aircraft_bus.get(), "uav0/SUBMAP", "before");
  ASSERT_TRUE(sides.ground_seen->WaitFor("uav0/SUBMAP", 1, 5s));
  sides.StopGround();
  for (int i = 0; i < 5; ++i) Publish(sides.aircraft_bus.get(), "uav0/SUBMAP", RandomBytes(3000, 40 + i));
  std::this_thread::sleep_for(300ms);
  sides.StartGround();
  // The new ground bridge asks for everything the aircraft still retains: the message from
  // before the outage comes again (a duplicate the merger ignores), the five sent into the void
  // arrive.
  ASSERT_TRUE(sides.ground_seen->WaitFor("uav0/SUBMAP", 7, 5s));
  std::this_thread::sleep_for(300ms);
  const auto got = sides.ground_seen->Get("uav0/SUBMAP");
  ASSERT_EQ(got.size(), 7u);
  EXPECT_EQ(got[1], "before");
  for (int i = 0; i < 5; ++i) EXPECT_EQ(got[2 + i], RandomBytes(3000, 40 + i));
}

TEST(LinkBridge, StaysUnderItsBudgetAndLetsSmallMessagesOvertake) {
  LinkOptions aircraft;
  aircraft.budget_bytes_per_s = 200000;
  TwoSides sides(aircraft);
  const Stopwatch clock;
  Publish(sides.aircraft_bus.get(), "uav0/SUBMAP", RandomBytes(400000, 1));
  std::this_thread::sleep_for(50ms);
  Publish(sides.aircraft_bus.get(), "uav0/SEQUENCE", "small");
  ASSERT_TRUE(sides.ground_seen->WaitFor("uav0/SUBMAP", 1, 10s));
  const double seconds = clock.ElapsedSeconds();
  const LinkCounts counts = sides.aircraft->counts();
  std::printf("400 kB at 200 kB/s: %.2f s, %lld bytes sent\n", seconds, static_cast<long long>(counts.bytes_sent));
  // 400 kB of payload plus headers at 200 kB/s: just over 2 s, never much faster.
  EXPECT_GT(seconds, 1.9);
  EXPECT_LT(seconds, 4.0);
  EXPECT_LT(counts.bytes_sent / seconds, 1.1 * 200000);
  const auto order = sides.ground_seen->order();
  ASSERT_EQ(order.size(), 2u);
  EXPECT_EQ(order[0], "uav0/SEQUENCE");  // sent while the large one was still going out
}

TEST(LinkBridge, SendsBackgroundChannelsOnlyWhenNothingElseWaits) {
  // A submap update going out, then a keyframe's picture, then a second update and a small
  // message: under a budget the picture waits for the first update; once begun it goes out to its
  // end with only the small message between its datagrams, then the second update.
  LinkOptions aircraft;
  aircraft.budget_bytes_per_s = 200000;
  aircraft.forward = "uav0/(SUBMAP|SEQUENCE|KEYFRAME_IMAGE)";
  TwoSides sides(aircraft);
  Publish(sides.aircraft_bus.get(), "uav0/SUBMAP", RandomBytes(100000, 5));
  std::this_thread::sleep_for(30ms);
  Publish(sides.aircraft_bus.get(), "uav0/KEYFRAME_IMAGE", RandomBytes(100000, 3));
  ASSERT_TRUE(sides.ground_seen->WaitFor("uav0/SUBMAP", 1, 10s));
  std::this_thread::sleep_for(100ms);  // the picture has begun
  Publish(sides.aircraft_bus.get(), "uav0/SUBMAP", RandomBytes(100000, 4));
  Publish(sides.aircraft_bus.get(), "uav0/SEQUENCE", "small");
  ASSERT_TRUE(sides.ground_seen->WaitFor("uav0/SUBMAP", 2, 10s));
  const auto order = sides.ground_seen->order();
  ASSERT_EQ(order.size(), 4u);
  EXPECT_EQ(order[0], "uav0/SUBMAP");
  EXPECT_EQ(order[1], "uav0/SEQUENCE");
  EXPECT_EQ(order[2], "uav0/KEYFRAME_IMAGE");
  EXPECT_EQ(order[3], "uav0/SUBMAP");
  EXPECT_EQ(sides.ground_seen->Get("uav0/KEYFRAME_IMAGE")[0], RandomBytes(100000, 3));
  EXPECT_EQ(sides.ground_seen->Get("uav0/SUBMAP")[1], RandomBytes(100000, 4));
}

// Pictures on a lossy link under a budget, with updates coming all the time: every lost
// datagram of the updates is still repaired (a picture held half-sent behind them held back the
// end below which the ground asks for repairs: the ground gave up on the updates).
TEST(LinkBridge, UpdatesSentDuringAPictureAreRepairedOnALossyLink) {
  LinkOptions aircraft;
  aircraft.budget_bytes_per_s = 300000;
  aircraft.loss = 0.05;
  aircraft.forward = "uav0/(SUBMAP|KEYFRAME_IMAGE)";
  TwoSides sides(aircraft);
  constexpr int kUpdates = 30, kPictures = 6;
  for (int i = 0; i < kUpdates; ++i) {
    if (i % 5 == 0) Publish(sides.aircraft_bus.get(), "uav0/KEYFRAME_IMAGE", RandomBytes(40000, 100 + i));
    Publish(sides.aircraft_bus.get(), "uav0/SUBMAP", RandomBytes(20000, i));
    std::this_thread::sleep_for(50ms);
  }
  ASSERT_TRUE(sides.ground_seen->WaitFor("uav0/SUBMAP", kUpdates, 30s));
  ASSERT_TRUE(sides.ground_seen->WaitFor("uav0/KEYFRAME_IMAGE", kPictures, 30s));
  const auto received = sides.ground_seen->Get("uav0/SUBMAP");  // repaired ones come later
  const std::set<std::string> updates(received.begin(), received.end());
  for (int i = 0; i < kUpdates; ++i) EXPECT_TRUE(updates.count(RandomBytes(20000, i))) << "update " << i;
  EXPECT_EQ(sides.ground->counts().messages_given_up, 0);
}

TEST(LinkBridge, DropsWhatWaitedTooLongUnderATightBudget) {
  LinkOptions aircraft;
  aircraft.budget_bytes_per_s = 20000;
  aircraft.max_queue_s = 0.5;
  TwoSides sides(aircraft);
  for (int i = 0; i < 8; ++i) Publish(sides.aircraft_bus.get(), "uav0/SUBMAP", RandomBytes(20000, i));
  std::this_thread::sleep_for(2500ms);
  const LinkCounts counts = sides.aircraft->counts();
  EXPECT_GE(counts.messages_expired, 4);
  EXPECT_EQ(counts.queued_bytes, 0);
  EXPECT_LE(sides.ground_seen->Get("uav0/SUBMAP").size() + counts.messages_expired, 8u);
}

TEST(LinkBridge, RefusesGarbageAndForeignDatagramsAndKeepsWorking) {
  TwoSides sides;
  const int port = sides.ground->local_port();
  const int s = socket(AF_INET, SOCK_DGRAM, 0);
  sockaddr_in to{};
  to.sin_family = AF_INET;
  to.sin_port = htons(static_cast<uint16_t>(port));
  to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  Rng rng(11);
  std::vector<std::string> garbage = {"", "STL1", std::string(2000, '\xff'),
                                      link::Encode(link::RepairRequest{123, {{1, {}}}}),
                                      link::Encode(link::LinkStatus{1, 5, 9})};  // retains past what it sent
  for (int i = 0; i < 300; ++i) garbage.push_back(RandomBytes(rng.UniformInt(1, 1500), 500 + i));
  std::string forged = link::Encode(link::Fragment(2, 0, "uav0/SUBMAP", "x", 1200)[0]);
  forged[30] = '\x7f';  // a fragment index far beyond its count
  garbage.push_back(forged);
  for (const auto& g : garbage) sendto(s, g.data(), g.size(), 0, reinterpret_cast<sockaddr*>(&to), sizeof(to));
  close(s);
  std::this_thread::sleep_for(300ms);
  EXPECT_GE(sides.ground->counts().datagrams_refused, 300);
  Publish(sides.aircraft_bus.get(), "uav0/SUBMAP", "after the garbage");
  ASSERT_TRUE(sides.ground_seen->WaitFor("uav0/SUBMAP", 1, 5s));
  EXPECT_EQ(sides.ground_seen->Get("uav0/SUBMAP")[0], "after the garbage");
}

// The security issue's rows, against the ground's bridge, from the aircraft's own address and
// port (its bridge down meanwhile, as if an attacker spoofed it): a 30-byte STATUS with session
// 2^64-1 (it made the ground ignore every real datagram), datagrams sealed with another key, and
// authentic datagrams sent again (replayed) or from an earlier run. None is acted on; each is
// counted; the real aircraft is heard again after.
TEST(LinkBridge, RefusesForgedAndReplayedDatagramsEvenFromThePeersAddress) {
  TwoSides sides;
  Publish(sides.aircraft_bus.get(), "uav0/SUBMAP", "before");
  ASSERT_TRUE(sides.ground_seen->WaitFor("uav0/SUBMAP", 1, 5s));
  sides.StopAircraft();
  const int s = socket(AF_INET, SOCK_DGRAM, 0);
  sockaddr_in from{}, to{};
  from.sin_family = to.sin_family = AF_INET;
  from.sin_addr.s_addr = to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  from.sin_port = htons(static_cast<uint16_t>(sides.aircraft_port));
  to.sin_port = htons(static_cast<uint16_t>(sides.ground->local_port()));
  ASSERT_EQ(bind(s, reinterpret_cast<sockaddr*>(&from), sizeof(from)), 0) << std::strerror(errno);
  const auto send = [&](const std::string& d) {
    sendto(s, d.data(), d.size(), 0, reinterpret_cast<sockaddr*>(&to), sizeof(to));
  };
  const link::LinkKey key = link::LoadKeyFile(sides.key_file);
  link::LinkKey wrong = key;
  wrong[0] ^= 1;
  const uint64_t now = static_cast<uint64_t>(WallUtime());
  send(link::Encode(link::LinkStatus{~uint64_t{0}, 0, 0}));  // unsealed
  link::Sealer forger(wrong, ~uint64_t{0});
  send(forger.Seal(link::Encode(link::LinkStatus{~uint64_t{0}, 0, 0})));
  send(forger.Seal(link::Encode(link::Fragment(~uint64_t{0}, 0, "uav0/SUBMAP", "forged", 1100)[0])));
  // 30 forged repair requests for everything the ground sent (each answered, 1,350x amplification).
  Publish(sides.ground_bus.get(), "uav0/SUBMAP_REQUEST", RandomBytes(50000, 77));
  std::this_thread::sleep_for(200ms);
  for (int i = 0; i < 30; ++i) send(link::Encode(link::RepairRequest{0, {{0, {}}, {1, {}}, {2, {}}}}));
  // With the key (a datagram recorded off the air): taken once, refused when sent again.
  link::Sealer recorded(link::DirectionKey(key, "aircraft"), now);
  const std::string authentic = recorded.Seal(link::Encode(link::Fragment(now, 0, "uav0/SUBMAP", "once", 1100)[0]));
  send(authentic);
  send(authentic);
  link::Sealer earlier_run(link::DirectionKey(key, "aircraft"),
                           now - 1000000);  // a run of the aircraft before this one
  send(earlier_run.Seal(link::Encode(link::Fragment(now - 1000000, 0, "uav0/SUBMAP", "earlier run", 1100)[0])));
  std::this_thread::sleep_for(300ms);
  close(s);
  const LinkCounts counts = sides.ground->counts();
  EXPECT_EQ(counts.datagrams_unauthenticated, 33);
  EXPECT_EQ(counts.datagrams_replayed, 2);
  EXPECT_EQ(counts.fragments_repaired, 0);
  const auto got = sides.ground_seen->Get("uav0/SUBMAP");
  EXPECT_EQ(got, (std::vector<std::string>{"before", "once"}));
  // The real aircraft comes back (a newer run) and is heard.
  sides.StartAircraft();
  Publish(sides.aircraft_bus.get(), "uav0/SUBMAP", "after");
  ASSERT_TRUE(sides.ground_seen->WaitFor("uav0/SUBMAP", 3, 5s));
  EXPECT_EQ(sides.ground_seen->Get("uav0/SUBMAP").back(), "after");
  EXPECT_TRUE(sides.ground->Status(0).authenticated);
}

// Between two bridges as a radio is: a relay that forwards each datagram to the other side (both
// bridges see the relay as their peer) and, once asked, also sends the aircraft's datagrams back
// to the aircraft, as an attacker who hears the link and sends from the ground's address would.
class Radio {
 public:
  Radio() : socket_(socket(AF_INET, SOCK_DGRAM, 0)) {
    sockaddr_in address = Loopback(0);
    bind(socket_, reinterpret_cast<sockaddr*>(&address), sizeof(address));
    socklen_t length = sizeof(address);
    getsockname(socket_, reinterpret_cast<sockaddr*>(&address), &length);
    port_ = ntohs(address.sin_port);
    timeval timeout{0, 20000};
    setsockopt(socket_, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof(timeout));
  }
  ~Radio() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
    close(socket_);
  }
  int port() const { return port_; }
  void Start(int aircraft_port, int ground_port) {
    aircraft_port_ = aircraft_port;
    ground_port_ = ground_port;
    thread_ = std::thread([this] { Relay(); });
  }
  void ReflectToTheAircraft(int datagrams) { reflect_ += datagrams; }
  int reflected() const { return reflected_; }

 private:
  static sockaddr_in Loopback(int port) {
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    address.sin_port = htons(static_cast<uint16_t>(port));
    return address;
  }
  void Relay() {
    std::vector<char> buffer(65536);
    while (!stop_) {
      sockaddr_in from{};
      socklen_t length = sizeof(from);
      const ssize_t size =
          recvfrom(socket_, buffer.data(), buffer.size(), 0, reinterpret_cast<sockaddr*>(&from), &length);
      if (size < 0) continue;
      const bool from_aircraft = ntohs(from.sin_port) == aircraft_port_;
      const sockaddr_in to = Loopback(from_aircraft ? ground_port_ : aircraft_port_);
      sendto(socket_, buffer.data(), static_cast<size_t>(size), 0, reinterpret_cast<const sockaddr*>(&to), sizeof(to));
      if (from_aircraft && reflect_ > 0) {
        --reflect_;
        ++reflected_;
        const sockaddr_in back = Loopback(aircraft_port_);
        sendto(socket_, buffer.data(), static_cast<size_t>(size), 0, reinterpret_cast<const sockaddr*>(&back),
               sizeof(back));
      }
    }
  }
  int socket_;
  int port_ = 0, aircraft_port_ = 0, ground_port_ = 0;
  std::atomic<int> reflect_{0}, reflected_{0};
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

// The security issue's row: one aircraft datagram sent back to the aircraft from the ground's
// address passed for the ground restarting (one key both ways, a session newer than the
// ground's), and the aircraft then refused every real ground datagram as replayed. Each
// direction has its own key now, and a bridge refuses its own session unsealed too.
TEST(LinkBridge, ADatagramReflectedBackToItsSenderIsRefused) {
  for (const bool insecure : {false, true}) {
    SCOPED_TRACE(insecure ? "insecure" : "authenticated");
    testing::TempDir dir;
    LinkOptions aircraft_options, ground_options;
    if (insecure) {
      aircraft_options.insecure = ground_options.insecure = true;
    } else {
      aircraft_options.key_file = ground_options.key_file = (dir.path() / "link.key").string();
      link::GenerateKeyFile(aircraft_options.key_file);
    }
    aircraft_options.side = "aircraft";
    ground_options.side = "ground";
    aircraft_options.forward = "uav0/SUBMAP";
    ground_options.forward = "uav0/SUBMAP_REQUEST";
    aircraft_options.report_interval_s = ground_options.report_interval_s = 0;
    Radio radio;
    const int aircraft_port = FreeUdpPort(), ground_port = FreeUdpPort();
    aircraft_options.listen = "127.0.0.1:" + std::to_string(aircraft_port);
    ground_options.listen = "127.0.0.1:" + std::to_string(ground_port);
    aircraft_options.peer = ground_options.peer = "127.0.0.1:" + std::to_string(radio.port());
    radio.Start(aircraft_port, ground_port);
    auto aircraft_bus = bus::OpenLcm("memq://"), ground_bus = bus::OpenLcm("memq://");
    Collector aircraft_seen(aircraft_bus.get(), "uav0/.*"), ground_seen(ground_bus.get(), "uav0/.*");
    // The ground station starts first, as in a flight: the aircraft's session is the newer.
    LinkBridge ground(ground_bus.get(), ground_options);
    std::this_thread::sleep_for(5ms);
    LinkBridge aircraft(aircraft_bus.get(), aircraft_options);
    bus::Dispatcher aircraft_dispatcher(aircraft_bus.get()), ground_dispatcher(ground_bus.get());
    aircraft_dispatcher.Start();
    ground_dispatcher.Start();
    ground.Start();
    aircraft.Start();
    Publish(aircraft_bus.get(), "uav0/SUBMAP", "before");
    Publish(ground_bus.get(), "uav0/SUBMAP_REQUEST", "ask before");
    ASSERT_TRUE(ground_seen.WaitFor("uav0/SUBMAP", 1, 5s));
    ASSERT_TRUE(aircraft_seen.WaitFor("uav0/SUBMAP_REQUEST", 1, 5s));
    radio.ReflectToTheAircraft(20);
    for (int i = 0; i < 10; ++i) Publish(aircraft_bus.get(), "uav0/SUBMAP", "during " + std::to_string(i));
    std::this_thread::sleep_for(600ms);  // statuses too (every 0.25 s)
    EXPECT_GE(radio.reflected(), 10);
    // The link still works both ways.
    Publish(ground_bus.get(), "uav0/SUBMAP_REQUEST", "ask after");
    Publish(aircraft_bus.get(), "uav0/SUBMAP", "after");
    EXPECT_TRUE(aircraft_seen.WaitFor("uav0/SUBMAP_REQUEST", 2, 5s)) << aircraft.Describe();
    EXPECT_TRUE(ground_seen.WaitFor("uav0/SUBMAP", 12, 5s)) << ground.Describe();
    const LinkCounts counts = aircraft.counts();
    EXPECT_EQ(counts.datagrams_refused, radio.reflected()) << aircraft.Describe();
    EXPECT_EQ(insecure ? counts.datagrams_replayed : counts.datagrams_unauthenticated, radio.reflected());
    aircraft_dispatcher.Stop();
    ground_dispatcher.Stop();
  }
}

// The security issue's row: a FRAME sent up to the aircraft's bridge was published on the
// aircraft's bus (and the tracker dropped the rest of the flight). Each side publishes only what
// the other is meant to send (link.accept).
TEST(LinkBridge, PublishesOnlyTheChannelsItAcceptsFromTheOtherSide) {
  LinkOptions aircraft, ground;
  aircraft.accept = "uav0/(SUBMAP_REQUEST|SEQUENCE)";
  ground.forward = "uav0/(SUBMAP_REQUEST|SEQUENCE|FRAME)";  // a ground that sends what it should not
  TwoSides sides(aircraft, ground);
  Publish(sides.ground_bus.get(), "uav0/FRAME", "a frame from the ground");
  Publish(sides.ground_bus.get(), "uav0/SUBMAP_REQUEST", "ask");
  ASSERT_TRUE(sides.aircraft_seen->WaitFor("uav0/SUBMAP_REQUEST", 1, 5s));
  std::this_thread::sleep_for(800ms);  // time for repair requests (repair_after_ms: 150), were it asked for again
  EXPECT_TRUE(sides.aircraft_seen->Get("uav0/FRAME").empty());
  EXPECT_EQ(sides.aircraft->counts().datagrams_refused, 1);  // and never asked for again
}

// Keyed buses on both sides (bus.key_file, each side its own key): what the aircraft's services
// tagged crosses and is published on the ground tagged with the ground's key; what a process
// without the aircraft bus's key publishes there is not sent.
TEST(LinkBridge, OnKeyedBusesOnlyTaggedMessagesCrossAndArriveTaggedForTheOtherBus) {
  const bus::BusAuthenticator aircraft_key(RandomSecret()), ground_key(RandomSecret());
  TwoSides sides({}, {}, aircraft_key, ground_key);
  bus::Subscriber ground_service(sides.ground_bus.get(), ground_key);
  std::mutex mutex;
  std::vector<int64_t> heard;
  ground_service.Subscribe<stitch::frame_ack_t>("uav0/SEQUENCE",
                                                [&](std::unique_ptr<stitch::frame_ack_t> ack, const std::string&) {
                                                  std::lock_guard<std::mutex> lock(mutex);
                                                  heard.push_back(ack->frame_index);
                                                });
  bus::Publisher service(sides.aircraft_bus.get(), "uav0", aircraft_key), forger(sides.aircraft_bus.get(), "uav0");
  stitch::frame_ack_t ack{};
  ack.frame_index = 666;
  forger.Publish("uav0/SEQUENCE", &ack);
  ack.frame_index = 1;
  service.Publish("uav0/SEQUENCE", &ack);
  ASSERT_TRUE(sides.ground_seen->WaitFor("uav0/SEQUENCE", 1, 5s));
  std::this_thread::sleep_for(500ms);
  const auto got = sides.ground_seen->Get("uav0/SEQUENCE");
  ASSERT_EQ(got.size(), 1u);
  EXPECT_TRUE(ground_key.Verify("uav0/SEQUENCE", reinterpret_cast<const uint8_t*>(got[0].data()), got[0].size()));
  {
    std::lock_guard<std::mutex> lock(mutex);
    EXPECT_EQ(heard, std::vector<int64_t>{1});
  }
  EXPECT_EQ(ground_service.rejected(), 0);
  EXPECT_EQ(sides.aircraft->counts().local_unauthenticated, 1);
  EXPECT_EQ(sides.ground->counts().echoes_suppressed, 1);  // its own publication, not sent back
  sides.ground_dispatcher->Stop();                         // before ground_service unsubscribes
}

TEST(LinkBridge, BadSettingsAreRefusedWithTheReason) {
  auto lcm = bus::OpenLcm("memq://");
  const auto refused = [&](LinkOptions options) {
    try {
      LinkBridge bridge(lcm.get(), options);
      return std::string();
    } catch (const Error& e) {
      return std::string(e.what());
    }
  };
  LinkOptions options;
  options.listen = "127.0.0.1:" + std::to_string(FreeUdpPort());
  EXPECT_NE(refused(options).find("stitch link keygen"), std::string::npos);  // no key, not insecure
  options.key_file = "/nonexistent/link.key";
  EXPECT_NE(refused(options).find("no link key file"), std::string::npos);
  testing::TempDir dir;
  options.key_file = (dir.path() / "link.key").string();
  link::GenerateKeyFile(options.key_file);
  EXPECT_NE(refused(options).find("link.side"), std::string::npos);  // a key, but which direction is whose?
  options.side = "satellite";
  EXPECT_NE(refused(options).find("aircraft or ground"), std::string::npos);
  options = LinkOptions();
  options.peer = "nowhere";
  EXPECT_NE(refused(options).find("ADDRESS:PORT"), std::string::npos);
  options = LinkOptions();
  options.accept = "uav0/(SUBMAP";
  options.insecure = true;
  options.listen = "127.0.0.1:" + std::to_string(FreeUdpPort());
  EXPECT_NE(refused(options).find("link.accept"), std::string::npos);
  options = LinkOptions();
  options.loss = 1.5;
  EXPECT_NE(refused(options).find("link.loss"), std::string::npos);
  options = LinkOptions();
  options.insecure = true;
  options.listen = "127.0.0.1:" + std::to_string(FreeUdpPort());
  options.peer = "no-such-host.invalid:7000";
  EXPECT_NE(refused(options).find("does not resolve"), std::string::npos);
  // Two bridges cannot listen on one port.
  options = LinkOptions();
  options.insecure = true;
  options.listen = "127.0.0.1:" + std::to_string(FreeUdpPort());
  LinkBridge first(lcm.get(), options);
  EXPECT_NE(refused(options).find("cannot listen"), std::string::npos);
}

}  // namespace
}  // namespace stitch
