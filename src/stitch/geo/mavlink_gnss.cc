#include "stitch/geo/mavlink_gnss.h"

#include <algorithm>
#include <cstring>

#include <sodium.h>

#include "stitch/util/error.h"

namespace stitch {
namespace {

constexpr uint8_t kMagicV1 = 0xFE, kMagicV2 = 0xFD;
constexpr size_t kHeaderV1 = 6, kHeaderV2 = 10, kChecksum = 2, kSignature = 13;
constexpr uint8_t kIncompatSigned = 0x01;
constexpr size_t kSignatureBytes = 6, kTimestampBytes = 6;
constexpr uint64_t kNewStreamSlack = 60 * 100'000;  // a minute, in the timestamp's 10 us units
constexpr size_t kGpsRawIntMinLength = 30, kGpsRawIntMaxLength = 52;
constexpr size_t kGlobalPositionIntLength = 28;

// The messages this decoder reads, and HEARTBEAT (which every sender sends: encoded by tests).
struct MessageInfo {
  uint32_t id;
  uint8_t crc_extra;
  size_t min_length, max_length;
};
constexpr MessageInfo kMessages[] = {
    {0, 50, 9, 9},
    {kMavlinkGpsRawInt, 24, kGpsRawIntMinLength, kGpsRawIntMaxLength},
    {kMavlinkGlobalPositionInt, 104, kGlobalPositionIntLength, kGlobalPositionIntLength},
};

const MessageInfo* FindMessage(uint32_t id) {
  for (const MessageInfo& m : kMessages) {
    if (m.id == id) return &m;
  }
  return nullptr;
}

template <class T>
T Read(const uint8_t* payload, size_t offset) {
  T value;
  std::memcpy(&value, payload + offset, sizeof(T));  // MAVLink is little-endian, as is every target here
  return value;
}

template <class T>
void Append(std::vector<uint8_t>* bytes, T value) {
  uint8_t raw[sizeof(T)];
  std::memcpy(raw, &value, sizeof(T));
  bytes->insert(bytes->end(), raw, raw + sizeof(T));
}

GnssFixType FixTypeOf(uint8_t gps_fix_type) {
  switch (gps_fix_type) {  // MAVLink's GPS_FIX_TYPE
    case 2:
      return GnssFixType::k2d;
    case 3:
      return GnssFixType::k3d;
    case 4:
      return GnssFixType::kDgps;
    case 5:
      return GnssFixType::kRtkFloat;
    case 6:
      return GnssFixType::kRtkFixed;
    case 7:
      return GnssFixType::k3d;  // static
    case 8:
      return GnssFixType::kDgps;  // PPP
    default:
      return GnssFixType::kNone;  // no GPS, no fix
  }
}

// The 48-bit signature of a MAVLink 2 frame: SHA-256 over the key, the frame from its marker
// through its CRC, then the link id and the 6-byte timestamp (`signed_part`: all of those bytes
// of the frame, `size` of them).
std::array<uint8_t, kSignatureBytes> MavlinkSignature(const std::array<uint8_t, 32>& key, const uint8_t* signed_part,
                                                      size_t size) {
  crypto_hash_sha256_state state;
  crypto_hash_sha256_init(&state);
  crypto_hash_sha256_update(&state, key.data(), key.size());
  crypto_hash_sha256_update(&state, signed_part, size);
  uint8_t digest[crypto_hash_sha256_BYTES];
  crypto_hash_sha256_final(&state, digest);
  std::array<uint8_t, kSignatureBytes> signature;
  std::memcpy(signature.data(), digest, kSignatureBytes);
  return signature;
}

}  // namespace

uint16_t MavlinkCrc(const uint8_t* data, size_t size, uint16_t crc) {
  for (size_t i = 0; i < size; ++i) {
    uint8_t t = data[i] ^ static_cast<uint8_t>(crc & 0xFF);
    t ^= static_cast<uint8_t>(t << 4);
    crc = static_cast<uint16_t>((crc >> 8) ^ (t << 8) ^ (t << 3) ^ (t >> 4));
  }
  return crc;
}

MavlinkGnssDecoder::MavlinkGnssDecoder(MavlinkGnssOptions options)
    : options_(options), newest_signed_(options.newest_signed_before) {
  if (options_.signing_key && sodium_init() < 0) throw Error("libsodium could not be initialized");
}

std::vector<GnssFix> MavlinkGnssDecoder::Feed(const uint8_t* data, size_t size, int64_t arrived_t_ns) {
  pending_.insert(pending_.end(), data, data + size);
  return Parse(arrived_t_ns, /*whole=*/false);
}

std::vector<GnssFix> MavlinkGnssDecoder::FeedDatagram(const uint8_t* data, size_t size, int64_t arrived_t_ns) {
  pending_.assign(data, data + size);
  return Parse(arrived_t_ns, /*whole=*/true);
}

std::vector<GnssFix> MavlinkGnssDecoder::Parse(int64_t arrived_t_ns, bool whole) {
  std::vector<GnssFix> fixes;
  size_t start = 0;
  const auto skip = [&](size_t n) {
    start += n;
    counts_.bytes_skipped += static_cast<int64_t>(n);
  };
  while (start < pending_.size()) {
    const uint8_t* frame = pending_.data() + start;
    const size_t available = pending_.size() - start;
    if (frame[0] != kMagicV1 && frame[0] != kMagicV2) {
      const auto next = std::find_if(pending_.begin() + static_cast<std::ptrdiff_t>(start), pending_.end(),
                                     [](uint8_t b) { return b == kMagicV1 || b == kMagicV2; });
      skip(static_cast<size_t>(next - pending_.begin()) - start);
      continue;
    }
    const bool v2 = frame[0] == kMagicV2;
    const size_t header = v2 ? kHeaderV2 : kHeaderV1;
    // A frame not all here yet: wait for the rest of the stream; a datagram has no rest.
    const auto incomplete = [&](size_t needed) { return available < needed; };
    if (incomplete(header)) {
      if (!whole) break;
      skip(1);
      continue;
    }
    const size_t length = frame[1];
    if (v2 && (frame[2] & ~kIncompatSigned) != 0) {  // flags it cannot know: MAVLink says drop it
      skip(1);
      continue;
    }
    const size_t size_with_crc = header + length + kChecksum;
    const size_t frame_size = size_with_crc + (v2 && (frame[2] & kIncompatSigned) ? kSignature : 0);
    const uint32_t id = v2 ? frame[7] | frame[8] << 8 | static_cast<uint32_t>(frame[9]) << 16 : frame[5];
    const MessageInfo* message = FindMessage(id);
    if (!message) {
      // Without its CRC_EXTRA an unknown message cannot be checked, so its length is not trusted
      // either: step over the marker alone and look for the next frame.
      skip(1);
      continue;
    }
    if (incomplete(frame_size)) {
      if (!whole) break;
      skip(1);
      continue;
    }
    uint16_t crc = MavlinkCrc(frame + 1, header - 1 + length);
    crc = MavlinkCrc(&message->crc_extra, 1, crc);
    const uint16_t stated = static_cast<uint16_t>(frame[header + length] | frame[header + length + 1] << 8);
    const bool length_ok = length <= message->max_length && (v2 ? length >= 1 : length >= message->min_length);
    if (crc != stated || !length_ok) {
      ++counts_.damaged;
      skip(1);
      continue;
    }
    if (options_.signing_key) {
      if (!v2 || !(frame[2] & kIncompatSigned)) {
        ++counts_.unsigned_frames;
        start += frame_size;
        continue;
      }
      if (!SignatureAccepted(frame, frame_size)) {
        start += frame_size;
        continue;
      }
    }
    ++counts_.frames;
    const int system = frame[v2 ? 5 : 3];
    const bool position = id == kMavlinkGpsRawInt || id == kMavlinkGlobalPositionInt;
    if (position && (options_.system_id == 0 || system == options_.system_id)) {
      // A trimmed MAVLink 2 payload (or one without the extensions) reads as zeros past its end.
      uint8_t payload[kGpsRawIntMaxLength] = {};
      std::memcpy(payload, frame + header, length);
      Decode(id, system, payload, arrived_t_ns, &fixes);
    }
    start += frame_size;
  }
  pending_.erase(pending_.begin(), pending_.begin() + static_cast<std::ptrdiff_t>(start));
  return fixes;
}

bool MavlinkGnssDecoder::SignatureAccepted(const uint8_t* frame, size_t frame_size) {
  const uint8_t* signature = frame + frame_size - kSignatureBytes;
  const auto expected = MavlinkSignature(*options_.signing_key, frame, frame_size - kSignatureBytes);
  if (sodium_memcmp(expected.data(), signature, kSignatureBytes) != 0) {
    ++counts_.bad_signatures;
    return false;
  }
  const uint8_t* link = frame + frame_size - kSignature;
  uint64_t timestamp = 0;
  for (size_t i = 0; i < kTimestampBytes; ++i) timestamp |= static_cast<uint64_t>(link[1 + i]) << (8 * i);
  const auto stream = std::make_tuple(int{frame[5]}, int{frame[6]}, int{link[0]});
  // As MAVLink's signing rules: within a stream each timestamp newer than the last; a stream not
  // seen before at most a minute older than the newest timestamp of any stream.
  const auto last = last_signed_.find(stream);
  const bool stale =
      last != last_signed_.end() ? timestamp <= last->second : timestamp + kNewStreamSlack < newest_signed_;
  if (stale) {
    ++counts_.replayed;
    return false;
  }
  last_signed_[stream] = timestamp;
  newest_signed_ = std::max(newest_signed_, timestamp);
  return true;
}

void MavlinkGnssDecoder::Decode(uint32_t id, int system, const uint8_t* payload, int64_t arrived_t_ns,
                                std::vector<GnssFix>* fixes) {
  const bool raw = id == kMavlinkGpsRawInt;
  const auto has_raw = [&] {
    return std::find(systems_with_raw_fixes_.begin(), systems_with_raw_fixes_.end(), system) !=
           systems_with_raw_fixes_.end();
  };
  if (raw && !has_raw()) systems_with_raw_fixes_.push_back(system);
  if (!raw && has_raw()) return;  // the receiver's own fixes come from this system: the estimate is not used
  GnssFix fix;
  fix.horizontal_accuracy_m = options_.stated_horizontal_accuracy_m;
  fix.vertical_accuracy_m = options_.stated_vertical_accuracy_m;
  if (raw) {
    fix.position.latitude_deg = Read<int32_t>(payload, 8) * 1e-7;
    fix.position.longitude_deg = Read<int32_t>(payload, 12) * 1e-7;
    const int32_t ellipsoid_mm = Read<int32_t>(payload, 30);
    fix.position.height_m = (ellipsoid_mm != 0 ? ellipsoid_mm : Read<int32_t>(payload, 16)) * 1e-3;
    fix.height_above_msl = ellipsoid_mm == 0;
    const uint16_t hdop = Read<uint16_t>(payload, 20), vdop = Read<uint16_t>(payload, 22);
    const uint32_t h_acc = Read<uint32_t>(payload, 34), v_acc = Read<uint32_t>(payload, 38);
    if (h_acc > 0) {
      fix.horizontal_accuracy_m = h_acc * 1e-3;
    } else if (hdop > 0 && hdop != UINT16_MAX) {
      fix.horizontal_accuracy_m = hdop * 0.01 * kMavlinkUserRangeErrorM;
    }
    if (v_acc > 0) {
      fix.vertical_accuracy_m = v_acc * 1e-3;
    } else if (vdop > 0 && vdop != UINT16_MAX) {
      fix.vertical_accuracy_m = vdop * 0.01 * kMavlinkUserRangeErrorM;
    }
    fix.type = FixTypeOf(payload[28]);
  } else {
    fix.position.latitude_deg = Read<int32_t>(payload, 4) * 1e-7;
    fix.position.longitude_deg = Read<int32_t>(payload, 8) * 1e-7;
    fix.position.height_m = Read<int32_t>(payload, 12) * 1e-3;
    fix.height_above_msl = true;
    fix.type = GnssFixType::k3d;
  }
  // 0, 0 is what a controller sends before its receiver has a position.
  const bool no_position = fix.position.latitude_deg == 0 && fix.position.longitude_deg == 0;
  if (!fix.usable() || no_position || !WhyNotAFix(fix).empty()) {
    ++counts_.refused;
    return;
  }
  // The sender's time of the fix (since the UNIX epoch or its boot; 0: none given), on the
  // caller's clock.
  const int64_t sent_t_ns =
      raw ? static_cast<int64_t>(std::min<uint64_t>(Read<uint64_t>(payload, 0), INT64_MAX / 1000)) * 1000
          : static_cast<int64_t>(Read<uint32_t>(payload, 0)) * 1'000'000;
  fix.t_ns = (sent_t_ns > 0 ? clocks_[system].Stamp(sent_t_ns, arrived_t_ns) : arrived_t_ns) -
             static_cast<int64_t>(options_.latency_s * 1e9);
  fix.t_ns = std::max(fix.t_ns, last_t_ns_ + 1);  // fixes in time order, as every track is
  last_t_ns_ = fix.t_ns;
  ++counts_.fixes;
  fixes->push_back(fix);
}

std::vector<uint8_t> EncodeMavlinkFrame(uint32_t message_id, std::vector<uint8_t> payload,
                                        const MavlinkFrameHeader& header) {
  const MessageInfo* message = FindMessage(message_id);
  std::vector<uint8_t> frame;
  if (header.version == 1) {
    frame = {kMagicV1,
             static_cast<uint8_t>(payload.size()),
             header.sequence,
             header.system_id,
             header.component_id,
             static_cast<uint8_t>(message_id)};
  } else {
    while (payload.size() > 1 && payload.back() == 0) payload.pop_back();  // MAVLink 2 trims trailing zeros
    frame = {kMagicV2,
             static_cast<uint8_t>(payload.size()),
             header.signing_key ? kIncompatSigned : uint8_t{0},
             0,
             header.sequence,
             header.system_id,
             header.component_id,
             static_cast<uint8_t>(message_id & 0xFF),
             static_cast<uint8_t>((message_id >> 8) & 0xFF),
             static_cast<uint8_t>((message_id >> 16) & 0xFF)};
  }
  frame.insert(frame.end(), payload.begin(), payload.end());
  uint16_t crc = MavlinkCrc(frame.data() + 1, frame.size() - 1);
  const uint8_t extra = message ? message->crc_extra : 0;
  crc = MavlinkCrc(&extra, 1, crc);
  frame.push_back(static_cast<uint8_t>(crc & 0xFF));
  frame.push_back(static_cast<uint8_t>(crc >> 8));
  if (header.version != 1 && header.signing_key) {
    if (sodium_init() < 0) throw Error("libsodium could not be initialized");
    frame.push_back(header.link_id);
    for (size_t i = 0; i < kTimestampBytes; ++i) {
      frame.push_back(static_cast<uint8_t>(header.signing_timestamp >> (8 * i)));
    }
    const auto signature = MavlinkSignature(*header.signing_key, frame.data(), frame.size());
    frame.insert(frame.end(), signature.begin(), signature.end());
  }
  return frame;
}

std::vector<uint8_t> MavlinkPayload(const MavlinkGpsRawInt& m) {
  std::vector<uint8_t> p;
  Append(&p, m.time_usec);
  Append(&p, m.lat_e7);
  Append(&p, m.lon_e7);
  Append(&p, m.alt_mm);
  Append(&p, m.eph);
  Append(&p, m.epv);
  Append(&p, m.vel);
  Append(&p, m.cog);
  Append(&p, m.fix_type);
  Append(&p, m.satellites_visible);
  Append(&p, m.alt_ellipsoid_mm);
  Append(&p, m.h_acc_mm);
  Append(&p, m.v_acc_mm);
  Append(&p, m.vel_acc);
  Append(&p, m.hdg_acc);
  Append(&p, m.yaw);
  return p;
}

std::vector<uint8_t> MavlinkPayload(const MavlinkGlobalPositionInt& m) {
  std::vector<uint8_t> p;
  Append(&p, m.time_boot_ms);
  Append(&p, m.lat_e7);
  Append(&p, m.lon_e7);
  Append(&p, m.alt_mm);
  Append(&p, m.relative_alt_mm);
  Append(&p, m.vx);
  Append(&p, m.vy);
  Append(&p, m.vz);
  Append(&p, m.hdg);
  return p;
}

}  // namespace stitch
