#include "stitch/geo/mavlink_gnss.h"

#include <array>
#include <optional>
#include <random>

#include <gtest/gtest.h>

namespace stitch {
namespace {

MavlinkGpsRawInt ZurichFix() {
  MavlinkGpsRawInt m;
  m.time_usec = 1'700'000'000'000'000;
  m.lat_e7 = 473684230;  // 47.368423
  m.lon_e7 = 85390540;   // 8.539054
  m.alt_mm = 459'873;    // above mean sea level
  m.alt_ellipsoid_mm = 507'120;
  m.eph = 80;  // HDOP 0.8
  m.epv = 120;
  m.fix_type = 3;
  m.satellites_visible = 14;
  m.h_acc_mm = 1'200;
  m.v_acc_mm = 2'500;
  return m;
}

MavlinkGnssOptions WithLatency(double s) {
  MavlinkGnssOptions options;
  options.latency_s = s;
  return options;
}

MavlinkGnssOptions OnlySystem(int id) {
  MavlinkGnssOptions options;
  options.system_id = id;
  return options;
}

std::vector<GnssFix> FeedAll(MavlinkGnssDecoder* decoder, const std::vector<uint8_t>& bytes, int64_t t_ns = 5) {
  return decoder->Feed(bytes.data(), bytes.size(), t_ns);
}

TEST(MavlinkGnss, TheCrcIsMcrf4xx) {
  // CRC-16/MCRF4XX's published check value: the CRC of the nine ASCII digits "123456789".
  const std::string digits = "123456789";
  EXPECT_EQ(MavlinkCrc(reinterpret_cast<const uint8_t*>(digits.data()), digits.size()), 0x6F91);
}

TEST(MavlinkGnss, ReadsTheReceiversFixFromMavlink1And2) {
  for (int version : {1, 2}) {
    MavlinkGnssDecoder decoder(WithLatency(0.1));
    MavlinkFrameHeader header;
    header.version = version;
    std::vector<uint8_t> payload = MavlinkPayload(ZurichFix());
    if (version == 1) payload.resize(30);  // MAVLink 1 carries no extensions
    const std::vector<GnssFix> fixes =
        FeedAll(&decoder, EncodeMavlinkFrame(kMavlinkGpsRawInt, payload, header), 2'000'000'000);
    ASSERT_EQ(fixes.size(), 1u) << "version " << version;
    const GnssFix& fix = fixes[0];
    EXPECT_EQ(fix.t_ns, 1'900'000'000) << "its arrival less the latency";
    EXPECT_NEAR(fix.position.latitude_deg, 47.368423, 1e-9);
    EXPECT_NEAR(fix.position.longitude_deg, 8.539054, 1e-9);
    EXPECT_EQ(fix.type, GnssFixType::k3d);
    if (version == 2) {
      EXPECT_NEAR(fix.position.height_m, 507.120, 1e-9) << "above the ellipsoid where the sender says";
      EXPECT_FALSE(fix.height_above_msl);
      EXPECT_NEAR(fix.horizontal_accuracy_m, 1.2, 1e-9);
      EXPECT_NEAR(fix.vertical_accuracy_m, 2.5, 1e-9);
    } else {
      EXPECT_NEAR(fix.position.height_m, 459.873, 1e-9) << "above mean sea level: all MAVLink 1 has";
      EXPECT_TRUE(fix.height_above_msl);
      EXPECT_NEAR(fix.horizontal_accuracy_m, 0.8 * kMavlinkUserRangeErrorM, 1e-9) << "from the HDOP";
      EXPECT_NEAR(fix.vertical_accuracy_m, 1.2 * kMavlinkUserRangeErrorM, 1e-9);
    }
    EXPECT_EQ(decoder.counts().frames, 1);
    EXPECT_EQ(decoder.counts().bytes_skipped, 0);
  }
}

// #42: a fix is timed by its message's own time, carried onto the caller's clock by the quickest
// arrival, not by when the telemetry brought it (here up to 250 ms late).
TEST(MavlinkGnss, AFixKeepsItsMessagesTimeWhateverItsArrivalJitters) {
  MavlinkGnssDecoder decoder(WithLatency(0.05));
  MavlinkGpsRawInt m = ZurichFix();
  std::mt19937 random(5);
  const int64_t local_minus_sent = 3'000'000'000'000;  // the two clocks' offset
  for (int i = 0; i < 50; ++i) {
    m.time_usec += 200'000;
    m.lat_e7 += 10;
    const int64_t sent_ns = static_cast<int64_t>(m.time_usec) * 1000;
    const int64_t jitter_ns = static_cast<int64_t>(random() % 250'000'000);
    const int64_t arrived = sent_ns + local_minus_sent + 40'000'000 + (i == 0 ? 0 : jitter_ns);
    const std::vector<GnssFix> fixes =
        FeedAll(&decoder, EncodeMavlinkFrame(kMavlinkGpsRawInt, MavlinkPayload(m)), arrived);
    ASSERT_EQ(fixes.size(), 1u);
    // The first arrived quickest: every fix is its time on the local clock plus the quickest
    // delay (40 ms), less the stated latency (50 ms).
    EXPECT_EQ(fixes[0].t_ns, sent_ns + local_minus_sent + 40'000'000 - 50'000'000) << i;
  }
  // Without a time in the message: its arrival, less the latency.
  MavlinkGlobalPositionInt estimate;
  estimate.lat_e7 = 473684230;
  estimate.lon_e7 = 85390540;
  MavlinkGnssDecoder untimed(WithLatency(0.05));
  const std::vector<GnssFix> fused =
      FeedAll(&untimed, EncodeMavlinkFrame(kMavlinkGlobalPositionInt, MavlinkPayload(estimate)), 7'000'000'000);
  ASSERT_EQ(fused.size(), 1u);
  EXPECT_EQ(fused[0].t_ns, 6'950'000'000);
}

TEST(MavlinkGnss, FindsFramesAmongOtherMessagesAndGarbageFedInAnyPieces) {
  std::vector<uint8_t> stream = {0x00, 0xFD, 0x13, 0xFE};  // garbage, two false markers among it
  std::vector<uint8_t> heartbeat = EncodeMavlinkFrame(0, {6, 0, 0, 0, 8, 0, 0, 4, 3});
  MavlinkGpsRawInt moved = ZurichFix();
  int expected = 0;
  for (int i = 0; i < 20; ++i) {
    stream.insert(stream.end(), heartbeat.begin(), heartbeat.end());
    moved.lat_e7 += 100;
    MavlinkFrameHeader header;
    header.sequence = static_cast<uint8_t>(i);
    const std::vector<uint8_t> frame = EncodeMavlinkFrame(kMavlinkGpsRawInt, MavlinkPayload(moved), header);
    stream.insert(stream.end(), frame.begin(), frame.end());
    ++expected;
    // A frame of an id this decoder does not know (it cannot be checked), with markers inside.
    const std::vector<uint8_t> other = EncodeMavlinkFrame(253, {0xFD, 0xFE, 0x18, 0x00, 0x21});
    stream.insert(stream.end(), other.begin(), other.end());
  }
  std::mt19937 random(7);
  for (int trial = 0; trial < 20; ++trial) {
    MavlinkGnssDecoder decoder;
    std::vector<GnssFix> fixes;
    for (size_t at = 0; at < stream.size();) {
      const size_t piece = std::min<size_t>(stream.size() - at, 1 + random() % 40);
      for (const GnssFix& fix : decoder.Feed(stream.data() + at, piece, static_cast<int64_t>(at))) fixes.push_back(fix);
      at += piece;
    }
    ASSERT_EQ(static_cast<int>(fixes.size()), expected) << "trial " << trial;
    for (size_t i = 1; i < fixes.size(); ++i) {
      EXPECT_GT(fixes[i].position.latitude_deg, fixes[i - 1].position.latitude_deg) << "in order, none twice";
      EXPECT_GT(fixes[i].t_ns, fixes[i - 1].t_ns);
    }
    EXPECT_GT(decoder.counts().bytes_skipped, 0) << "the garbage and the unknown messages";
  }
}

TEST(MavlinkGnss, UsesTheFusedEstimateOnlyFromASystemWithoutReceiverFixes) {
  MavlinkGnssDecoder decoder;
  MavlinkGlobalPositionInt estimate;
  estimate.lat_e7 = 473684230;
  estimate.lon_e7 = 85390540;
  estimate.alt_mm = 460'000;
  const std::vector<GnssFix> fused =
      FeedAll(&decoder, EncodeMavlinkFrame(kMavlinkGlobalPositionInt, MavlinkPayload(estimate)));
  ASSERT_EQ(fused.size(), 1u);
  EXPECT_NEAR(fused[0].position.height_m, 460.0, 1e-9);
  EXPECT_EQ(fused[0].horizontal_accuracy_m, MavlinkGnssOptions().stated_horizontal_accuracy_m);
  EXPECT_EQ(FeedAll(&decoder, EncodeMavlinkFrame(kMavlinkGpsRawInt, MavlinkPayload(ZurichFix()))).size(), 1u);
  EXPECT_TRUE(FeedAll(&decoder, EncodeMavlinkFrame(kMavlinkGlobalPositionInt, MavlinkPayload(estimate))).empty())
      << "the receiver's own fixes come from this system now";
  MavlinkFrameHeader other;
  other.system_id = 2;
  EXPECT_EQ(FeedAll(&decoder, EncodeMavlinkFrame(kMavlinkGlobalPositionInt, MavlinkPayload(estimate), other)).size(),
            1u);
  MavlinkGnssDecoder only_first(OnlySystem(1));
  EXPECT_TRUE(
      FeedAll(&only_first, EncodeMavlinkFrame(kMavlinkGlobalPositionInt, MavlinkPayload(estimate), other)).empty());
}

TEST(MavlinkGnss, RefusesWhatIsNoFix) {
  MavlinkGnssDecoder decoder;
  MavlinkGpsRawInt no_lock = ZurichFix();
  no_lock.fix_type = 1;
  MavlinkGpsRawInt at_zero = ZurichFix();
  at_zero.lat_e7 = at_zero.lon_e7 = 0;
  MavlinkGpsRawInt off_earth = ZurichFix();
  off_earth.lat_e7 = 950000000;  // 95 degrees
  for (const MavlinkGpsRawInt& m : {no_lock, at_zero, off_earth}) {
    EXPECT_TRUE(FeedAll(&decoder, EncodeMavlinkFrame(kMavlinkGpsRawInt, MavlinkPayload(m))).empty());
  }
  EXPECT_EQ(decoder.counts().refused, 3);
  EXPECT_EQ(decoder.counts().fixes, 0);
}

TEST(MavlinkGnss, ADamagedFrameIsCountedAndTheNextOneStillRead) {
  const std::vector<uint8_t> good = EncodeMavlinkFrame(kMavlinkGpsRawInt, MavlinkPayload(ZurichFix()));
  for (size_t at = 1; at < good.size(); ++at) {
    std::vector<uint8_t> bytes = good;
    bytes[at] ^= 0x40;
    bytes.insert(bytes.end(), good.begin(), good.end());
    MavlinkGnssDecoder datagrams;
    EXPECT_EQ(datagrams.FeedDatagram(bytes.data(), bytes.size(), 1).size(), 1u)
        << "byte " << at << " altered: only the intact frame gives a fix, at once";
    // In a stream a damaged length may hold the next frame back until the bytes it claims came.
    MavlinkGnssDecoder stream;
    std::vector<GnssFix> fixes = FeedAll(&stream, bytes);
    const std::vector<uint8_t> more(300, 0);
    for (const GnssFix& fix : FeedAll(&stream, more)) fixes.push_back(fix);
    EXPECT_EQ(fixes.size(), 1u) << "byte " << at << " altered, in a stream";
  }
}

TEST(MavlinkGnss, ArbitraryBytesNeverCrashOrGiveAFix) {
  std::mt19937 random(11);
  MavlinkGnssDecoder decoder;
  const std::vector<uint8_t> good = EncodeMavlinkFrame(kMavlinkGpsRawInt, MavlinkPayload(ZurichFix()));
  int64_t fixes = 0;
  for (int round = 0; round < 3000; ++round) {
    std::vector<uint8_t> bytes(random() % 300);
    for (auto& b : bytes) b = static_cast<uint8_t>(random());
    // Often a marker and a known id, so the length, flag and CRC paths are taken.
    if (!bytes.empty() && round % 2 == 0) {
      const std::vector<uint8_t> head(good.begin(), good.begin() + std::min(good.size(), bytes.size()));
      std::copy(head.begin(), head.begin() + static_cast<std::ptrdiff_t>(std::min(head.size(), size_t{10})),
                bytes.begin());
    }
    fixes += static_cast<int64_t>(decoder.Feed(bytes.data(), bytes.size(), round).size());
  }
  EXPECT_EQ(fixes, 0) << "a random frame passes the CRC about once in 65536";
  // The same bytes through a decoder that checks signatures.
  MavlinkGnssOptions signing;
  signing.signing_key = std::array<uint8_t, 32>{};
  MavlinkGnssDecoder checking(signing);
  std::mt19937 again(11);
  for (int round = 0; round < 3000; ++round) {
    std::vector<uint8_t> bytes(again() % 300);
    for (auto& b : bytes) b = static_cast<uint8_t>(again());
    bytes.insert(bytes.begin(), good.begin(), good.begin() + 3);
    bytes[2] |= 0x01;  // flagged signed
    EXPECT_TRUE(checking.Feed(bytes.data(), bytes.size(), round).empty());
  }
  // A frame the garbage began is settled within 280 bytes; then a good frame is read.
  const std::vector<uint8_t> zeros(300, 0);
  EXPECT_TRUE(FeedAll(&decoder, zeros, 1'000'000).empty());
  EXPECT_EQ(FeedAll(&decoder, good, 1'000'001).size(), 1u) << "and the decoder still reads a good frame after";
}

// MAVLink 2 message signing, against another implementation's frame: a HEARTBEAT signed with a
// published test key (the signed-heartbeat test vector of the Rust `mavlink` crate's tests).
TEST(MavlinkGnss, ChecksASignatureAsMavlinkDefinesIt) {
  const std::array<uint8_t, 32> key = {0x00, 0x01, 0xf2, 0xe3, 0xd4, 0xc5, 0xb6, 0xa7, 0x98, 0x00, 0x70,
                                       0x76, 0x34, 0x32, 0x00, 0x16, 0x22, 0x42, 0x00, 0xcc, 0xff, 0x7a,
                                       0x00, 0x52, 0x75, 0x73, 0x74, 0x00, 0x4d, 0x41, 0x56, 0xb3};
  const std::vector<uint8_t> heartbeat = {0xfd, 0x09, 0x01, 0x00, 0xef, 0x01, 0x02, 0x00, 0x00, 0x00, 0x05, 0x00,
                                          0x00, 0x00, 0x02, 0x03, 0x59, 0x03, 0x03, 0xc9, 0x8b, 0x00, 0xff, 0xff,
                                          0xff, 0xff, 0xff, 0xff, 0x27, 0x18, 0xb1, 0x68, 0xcc, 0xf5};
  MavlinkGnssOptions options;
  options.signing_key = key;
  MavlinkGnssDecoder decoder(options);
  FeedAll(&decoder, heartbeat);
  EXPECT_EQ(decoder.counts().frames, 1);
  EXPECT_EQ(decoder.counts().bad_signatures, 0);
  // Our encoder signs it the same way.
  MavlinkFrameHeader header;
  header.sequence = 0xef;
  header.system_id = 1;
  header.component_id = 2;
  header.signing_key = key;
  header.signing_timestamp = 0xffffffffffff;
  EXPECT_EQ(EncodeMavlinkFrame(0, {0x05, 0x00, 0x00, 0x00, 0x02, 0x03, 0x59, 0x03, 0x03}, header), heartbeat);
  // One bit of the signature, or of the timestamp it covers, changed: refused.
  for (size_t at : {heartbeat.size() - 1, heartbeat.size() - 8}) {
    std::vector<uint8_t> altered = heartbeat;
    altered[at] ^= 0x01;
    MavlinkGnssDecoder fresh(options);
    FeedAll(&fresh, altered);
    EXPECT_EQ(fresh.counts().frames, 0) << "byte " << at;
    EXPECT_EQ(fresh.counts().bad_signatures, 1) << "byte " << at;
  }
}

// With a signing key, a fix is taken only from a frame signed with it, once: an unsigned frame, a
// MAVLink 1 frame, one signed with another key, one sent again (its timestamp no newer than its
// stream's last) and a new stream's frame from long before the newest are refused and counted;
// without a key, signed frames are read as any other.
TEST(MavlinkGnss, WithASigningKeyTakesOnlyFixesSignedWithIt) {
  std::array<uint8_t, 32> key{}, other{};
  for (size_t i = 0; i < key.size(); ++i) {
    key[i] = static_cast<uint8_t>(3 * i + 1);
    other[i] = static_cast<uint8_t>(5 * i + 2);
  }
  const auto frame = [&](const std::optional<std::array<uint8_t, 32>>& signing, uint64_t timestamp, int version = 2,
                         uint8_t link = 0) {
    MavlinkFrameHeader header;
    header.version = version;
    header.signing_key = signing;
    header.signing_timestamp = timestamp;
    header.link_id = link;
    std::vector<uint8_t> payload = MavlinkPayload(ZurichFix());
    if (version == 1) payload.resize(30);
    return EncodeMavlinkFrame(kMavlinkGpsRawInt, payload, header);
  };
  MavlinkGnssOptions options;
  options.signing_key = key;
  MavlinkGnssDecoder decoder(options);
  constexpr uint64_t kNow = 370'000'000'000'000;  // 10 us units since 2015: late 2026
  EXPECT_EQ(FeedAll(&decoder, frame(key, kNow)).size(), 1u);
  EXPECT_EQ(FeedAll(&decoder, frame(key, kNow + 10)).size(), 1u);
  EXPECT_TRUE(FeedAll(&decoder, frame(std::nullopt, 0)).empty());
  EXPECT_TRUE(FeedAll(&decoder, frame(std::nullopt, 0, /*version=*/1)).empty());
  EXPECT_TRUE(FeedAll(&decoder, frame(other, kNow + 20)).empty());
  EXPECT_TRUE(FeedAll(&decoder, frame(key, kNow + 10)).empty()) << "sent again";
  EXPECT_TRUE(FeedAll(&decoder, frame(key, kNow + 5)).empty()) << "older than its stream's last";
  EXPECT_EQ(FeedAll(&decoder, frame(key, kNow - 100, 2, /*link=*/1)).size(), 1u) << "another link, within a minute";
  EXPECT_TRUE(FeedAll(&decoder, frame(key, kNow - 7'000'000, 2, /*link=*/2)).empty())
      << "a new link's frame 70 s older than the newest";
  EXPECT_EQ(decoder.counts().fixes, 3);
  EXPECT_EQ(decoder.counts().unsigned_frames, 2);
  EXPECT_EQ(decoder.counts().bad_signatures, 1);
  EXPECT_EQ(decoder.counts().replayed, 3);
  // In a stream cut anywhere, and as datagrams, the same.
  const std::vector<uint8_t> signed_frame = frame(key, kNow + 100);
  MavlinkGnssDecoder pieces(options);
  size_t fixes = 0;
  for (size_t at = 0; at < signed_frame.size(); at += 5) {
    fixes += pieces.Feed(signed_frame.data() + at, std::min<size_t>(5, signed_frame.size() - at), 1).size();
  }
  EXPECT_EQ(fixes, 1u);
  MavlinkGnssDecoder datagrams(options);
  EXPECT_EQ(datagrams.FeedDatagram(signed_frame.data(), signed_frame.size(), 1).size(), 1u);
  // Without a key, signatures are not checked.
  MavlinkGnssDecoder unchecked;
  EXPECT_EQ(FeedAll(&unchecked, frame(other, 1)).size(), 1u);
}

}  // namespace
}  // namespace stitch
