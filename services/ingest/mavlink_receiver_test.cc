#include "services/ingest/mavlink_receiver.h"

#include <arpa/inet.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <condition_variable>
#include <mutex>
#include <thread>

#include <gtest/gtest.h>

#include "stitch/util/error.h"
#include "stitch/util/time.h"

namespace stitch {
namespace {

void SendTo(int port, const std::vector<uint8_t>& bytes) {
  const int s = socket(AF_INET, SOCK_DGRAM, 0);
  sockaddr_in to{};
  to.sin_family = AF_INET;
  to.sin_port = htons(static_cast<uint16_t>(port));
  inet_pton(AF_INET, "127.0.0.1", &to.sin_addr);
  sendto(s, bytes.data(), bytes.size(), 0, reinterpret_cast<const sockaddr*>(&to), sizeof(to));
  close(s);
}

TEST(MavlinkReceiver, PublishesTheFixesOfTheDatagramsItGetsStampedWithTheWallClock) {
  std::mutex mutex;
  std::condition_variable arrived;
  std::vector<GnssFix> fixes;
  MavlinkGnssOptions options;
  options.latency_s = 0.2;
  MavlinkReceiver receiver("127.0.0.1:0", options, [&](const GnssFix& fix) {
    std::lock_guard<std::mutex> lock(mutex);
    fixes.push_back(fix);
    arrived.notify_all();
  });
  ASSERT_GT(receiver.port(), 0);
  MavlinkGpsRawInt raw;
  raw.lat_e7 = 473684230;
  raw.lon_e7 = 85390540;
  raw.alt_mm = 460'000;
  raw.fix_type = 3;
  raw.eph = 90;
  const std::vector<uint8_t> frame = EncodeMavlinkFrame(kMavlinkGpsRawInt, MavlinkPayload(raw));
  std::vector<uint8_t> damaged = frame;
  damaged[12] ^= 1;
  const int64_t before = WallClockNs();
  SendTo(receiver.port(), {0xFD, 0xFE, 0x00, 0x42});  // garbage
  SendTo(receiver.port(), damaged);
  SendTo(receiver.port(), frame);
  std::unique_lock<std::mutex> lock(mutex);
  ASSERT_TRUE(arrived.wait_for(lock, std::chrono::seconds(10), [&] { return !fixes.empty(); }));
  const int64_t after = WallClockNs();
  EXPECT_EQ(fixes.size(), 1u) << "the damaged frame gives none";
  EXPECT_NEAR(fixes[0].position.latitude_deg, 47.368423, 1e-9);
  EXPECT_GE(fixes[0].t_ns, before - 200'000'000);
  EXPECT_LE(fixes[0].t_ns, after - 200'000'000) << "its arrival on the wall clock, less the latency";
  lock.unlock();
  const MavlinkGnssCounts counts = receiver.counts();
  EXPECT_EQ(counts.fixes, 1);
  EXPECT_EQ(counts.damaged, 1);
  EXPECT_NE(receiver.Describe().find("1 GNSS fixes from MAVLink (3 datagrams"), std::string::npos)
      << receiver.Describe();
}

TEST(MavlinkReceiver, RefusesAnAddressItCannotListenOn) {
  EXPECT_THROW(MavlinkReceiver("14550", {}, [](const GnssFix&) {}), Error) << "no port";
  EXPECT_THROW(MavlinkReceiver("no.such.host.invalid:14550", {}, [](const GnssFix&) {}), Error);
  MavlinkReceiver first("127.0.0.1:0", {}, [](const GnssFix&) {});
  EXPECT_THROW(MavlinkReceiver("127.0.0.1:" + std::to_string(first.port()), {}, [](const GnssFix&) {}), Error)
      << "a port in use";
}

}  // namespace
}  // namespace stitch
