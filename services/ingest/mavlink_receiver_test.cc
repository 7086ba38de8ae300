#include "services/ingest/mavlink_receiver.h"

#include <arpa/inet.h>
#include <pty.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <optional>
#include <thread>

#include <gtest/gtest.h>

#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"
#include "stitch/util/time.h"

namespace stitch {
namespace {

// A receiver's 3D fix over Zurich (HDOP 0.9).
MavlinkGpsRawInt ZurichFix() {
  MavlinkGpsRawInt raw;
  raw.lat_e7 = 473684230;
  raw.lon_e7 = 85390540;
  raw.alt_mm = 460'000;
  raw.fix_type = 3;
  raw.eph = 90;
  return raw;
}

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
  const MavlinkGpsRawInt raw = ZurichFix();
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
  // Its altitude above mean sea level (no alt_ellipsoid) raised to the ellipsoid by the geoid.
  EXPECT_NEAR(fixes[0].position.height_m, 460.0 + 47.25, 0.2);
  EXPECT_FALSE(fixes[0].height_above_msl);
  EXPECT_GE(fixes[0].t_ns, before - 200'000'000);
  EXPECT_LE(fixes[0].t_ns, after - 200'000'000) << "its arrival on the wall clock, less the latency";
  lock.unlock();
  const MavlinkGnssCounts counts = receiver.counts();
  EXPECT_EQ(counts.fixes, 1);
  EXPECT_EQ(counts.damaged, 1);
  EXPECT_NE(receiver.Describe().find("1 GNSS fixes from MAVLink (3 datagrams"), std::string::npos)
      << receiver.Describe();
}

// With the controller's signing key, a forged fix (unsigned, or signed with another key) and a
// signed one sent again are refused and counted; the signed one is published.
TEST(MavlinkReceiver, WithASigningKeyPublishesOnlyTheControllersSignedFixes) {
  std::mutex mutex;
  std::condition_variable arrived;
  std::vector<GnssFix> fixes;
  std::array<uint8_t, 32> key{}, forged{};
  key.fill(0x5A);
  forged.fill(0xA5);
  MavlinkGnssOptions options;
  options.signing_key = key;
  MavlinkReceiver receiver("127.0.0.1:0", options, [&](const GnssFix& fix) {
    std::lock_guard<std::mutex> lock(mutex);
    fixes.push_back(fix);
    arrived.notify_all();
  });
  const MavlinkGpsRawInt raw = ZurichFix();
  MavlinkFrameHeader header;
  header.signing_timestamp = 370'000'000'000'000;
  const auto frame = [&](const std::optional<std::array<uint8_t, 32>>& signing, int32_t lat_e7) {
    MavlinkGpsRawInt m = raw;
    m.lat_e7 = lat_e7;
    header.signing_key = signing;
    ++header.signing_timestamp;
    return EncodeMavlinkFrame(kMavlinkGpsRawInt, MavlinkPayload(m), header);
  };
  const std::vector<uint8_t> real = frame(key, raw.lat_e7);
  SendTo(receiver.port(), frame(std::nullopt, 480000000));
  SendTo(receiver.port(), frame(forged, 480000000));
  SendTo(receiver.port(), real);
  SendTo(receiver.port(), real);  // sent again
  SendTo(receiver.port(), frame(key, raw.lat_e7 + 10));
  std::unique_lock<std::mutex> lock(mutex);
  ASSERT_TRUE(arrived.wait_for(lock, std::chrono::seconds(10), [&] { return fixes.size() >= 2; }));
  lock.unlock();
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  lock.lock();
  ASSERT_EQ(fixes.size(), 2u);
  for (const GnssFix& fix : fixes) EXPECT_NEAR(fix.position.latitude_deg, 47.368423, 1e-5) << "never the forged 48.0";
  lock.unlock();
  const MavlinkGnssCounts counts = receiver.counts();
  EXPECT_EQ(counts.unsigned_frames, 1);
  EXPECT_EQ(counts.bad_signatures, 1);
  EXPECT_EQ(counts.replayed, 1);
  EXPECT_NE(receiver.Describe().find("1 unsigned, 1 with a wrong signature, 1 replayed"), std::string::npos)
      << receiver.Describe();
}

// MAVLink replay protection across a restart (#45): a receiver started again refused nothing a
// recording of the last run's signed frames held (each stream's last timestamp was the
// decoder's). With the state file, the new receiver holds every stream to the newest timestamp
// the last one took: frames recorded more than a minute before are refused, fresh ones taken.
TEST(MavlinkReceiver, ASigningStateFileKeepsReplaysOutAfterARestart) {
  testing::TempDir dir;
  const std::string state = dir / "mavlink-signing.state";
  std::array<uint8_t, 32> key{};
  key.fill(0x5A);
  MavlinkGnssOptions options;
  options.signing_key = key;
  constexpr uint64_t kFirst = 370'000'000'000'000, kMinute = 6'000'000;  // 10 us units
  const auto frame = [&](uint64_t timestamp) {
    MavlinkFrameHeader header;
    header.signing_key = key;
    header.signing_timestamp = timestamp;
    return EncodeMavlinkFrame(kMavlinkGpsRawInt, MavlinkPayload(ZurichFix()), header);
  };
  // The first run takes frames over two minutes of the controller's clock.
  const std::vector<uint8_t> recorded = frame(kFirst);
  const auto fixes_of = [&](const std::vector<std::vector<uint8_t>>& frames) {
    std::mutex mutex;
    std::vector<GnssFix> fixes;
    {
      MavlinkReceiver receiver(
          "127.0.0.1:0", options,
          [&](const GnssFix& fix) {
            std::lock_guard<std::mutex> lock(mutex);
            fixes.push_back(fix);
          },
          state);
      for (const auto& f : frames) SendTo(receiver.port(), f);
      for (int wait = 0; wait < 100 && receiver.counts().frames < static_cast<int64_t>(frames.size()); ++wait) {
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
      }
    }  // stops: the newest timestamp is kept
    return fixes.size();
  };
  EXPECT_EQ(fixes_of({recorded, frame(kFirst + kMinute), frame(kFirst + 2 * kMinute)}), 3u);
  ASSERT_TRUE(std::filesystem::exists(state));
  // Started again: the recording's first frame (two minutes old) is refused; a frame within the
  // minute a new stream may lag, and a fresh one, are taken.
  EXPECT_EQ(fixes_of({recorded}), 0u);
  EXPECT_EQ(fixes_of({frame(kFirst + 2 * kMinute - kMinute / 2), frame(kFirst + 3 * kMinute)}), 2u);
  // Without the file (the protection the decoder alone gives), the recording is taken again.
  std::filesystem::remove(state);
  EXPECT_EQ(fixes_of({recorded}), 1u);
  // A state file that holds no timestamp is an error that says what to do.
  std::ofstream(state) << "garbage\n";
  try {
    MavlinkReceiver receiver(
        "127.0.0.1:0", options, [](const GnssFix&) {}, state);
    ADD_FAILURE() << "a damaged state file was taken";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("remove it"), std::string::npos) << e.what();
  }
}

// A controller wired to a serial port: the frames come as a byte stream, cut anywhere. A
// pseudo-terminal stands in for the port.
TEST(MavlinkReceiver, ReadsTheFixesOfAControllerOnASerialPort) {
  int controller = -1, port_side = -1;
  ASSERT_EQ(openpty(&controller, &port_side, nullptr, nullptr, nullptr), 0);
  const std::string device = ttyname(port_side);
  std::mutex mutex;
  std::condition_variable arrived;
  std::vector<GnssFix> fixes;
  MavlinkSerialPort port;
  port.device = device;
  port.baud = 115200;
  MavlinkReceiver receiver(port, {}, [&](const GnssFix& fix) {
    std::lock_guard<std::mutex> lock(mutex);
    fixes.push_back(fix);
    arrived.notify_all();
  });
  close(port_side);  // the receiver holds its own descriptor
  MavlinkGpsRawInt raw = ZurichFix();
  std::vector<uint8_t> stream = {0x55, 0xFE, 0x01};  // line noise first
  for (int i = 0; i < 5; ++i) {
    raw.lat_e7 += 10;
    const std::vector<uint8_t> frame = EncodeMavlinkFrame(kMavlinkGpsRawInt, MavlinkPayload(raw));
    stream.insert(stream.end(), frame.begin(), frame.end());
  }
  // Written in pieces of 7 bytes, each a little after the last: no frame arrives whole.
  for (size_t at = 0; at < stream.size(); at += 7) {
    ASSERT_GT(write(controller, stream.data() + at, std::min<size_t>(7, stream.size() - at)), 0);
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  std::unique_lock<std::mutex> lock(mutex);
  ASSERT_TRUE(arrived.wait_for(lock, std::chrono::seconds(10), [&] { return fixes.size() >= 5; }))
      << receiver.Describe();
  for (size_t i = 1; i < fixes.size(); ++i)
    EXPECT_GT(fixes[i].position.latitude_deg, fixes[i - 1].position.latitude_deg);
  lock.unlock();
  EXPECT_NE(receiver.Describe().find("reads of " + device), std::string::npos) << receiver.Describe();
  close(controller);

  MavlinkSerialPort unknown_rate = port;
  unknown_rate.baud = 12345;
  EXPECT_THROW(MavlinkReceiver(unknown_rate, {}, [](const GnssFix&) {}), Error);
  MavlinkSerialPort missing;
  missing.device = "/dev/no-such-controller";
  EXPECT_THROW(MavlinkReceiver(missing, {}, [](const GnssFix&) {}), Error);
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
