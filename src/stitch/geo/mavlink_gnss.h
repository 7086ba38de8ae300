#pragma once
// GNSS fixes from a flight controller's MAVLink stream (ArduPilot, PX4): a small decoder of just
// the two messages that carry a position, not a MAVLink library.
//
// Frames of MAVLink 1 (0xFE) and 2 (0xFD) are found in a byte stream (a serial line, or UDP
// datagrams, fed in any pieces); each is checked by its CRC-16/MCRF4XX, seeded with the message's
// CRC_EXTRA as MAVLink defines it, before any field is read. Read:
//
// - GPS_RAW_INT (24): the receiver's own fix. Height above the ellipsoid from alt_ellipsoid
//   where the sender fills it (MAVLink 2 extension), else its altitude above mean sea level,
//   marked so (the ingest raises it to the ellipsoid by the geoid: geoid.h). Accuracy from
//   h_acc / v_acc where given, else HDOP / VDOP times kMavlinkUserRangeErrorM. The fix type as
//   the receiver states it (no fix: not used).
// - GLOBAL_POSITION_INT (33): the controller's fused estimate, used only from a system that sends
//   no GPS_RAW_INT; it states no accuracy (stated_*_accuracy_m) and its altitude is above mean sea
//   level.
//
// Everything else (other messages, frames of unknown ids, damaged frames, garbage between frames)
// is stepped over and counted. Without a signing key, MAVLink 2 signed frames are read and their
// signature is not checked. With one (MavlinkGnssOptions::signing_key, the 32-byte secret the
// flight controller signs with), only MAVLink 2 frames signed with it are read: the signature
// (the first 48 bits of SHA-256 over the key, the frame from its marker to its CRC, the link id
// and the timestamp, as MAVLink 2 message signing defines it) must check out, and the timestamp
// must be newer than the last one accepted from the same system, component and link, and for a
// stream not seen before at most a minute older than the newest of any (a frame replayed, or one
// recorded earlier, is refused); unsigned frames and MAVLink 1 are refused. The streams' state
// is the decoder's; a new decoder (the ingest started again) holds every stream to the newest
// timestamp an earlier one accepted where it is given it (MavlinkGnssOptions::newest_signed_before,
// which the ingest keeps in a file), so a frame recorded more than a minute before is refused
// after a restart too.
// Each refusal is counted. A fix's time is on the caller's clock (the live camera's, so fixes and
// frames share it): the message's own time (GPS_RAW_INT's time_usec, GLOBAL_POSITION_INT's
// time_boot_ms) carried onto it by the quickest arrival of the sender's fixes (ReceiverClock:
// the telemetry's jitter does not move a fix), less MavlinkGnssOptions::latency_s; where the
// message gives no time, its arrival less the latency.

#include <array>
#include <cstddef>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <tuple>
#include <vector>

#include "stitch/geo/gnss_fix.h"
#include "stitch/geo/receiver_clock.h"

namespace stitch {

// Metres of position error per unit of dilution of precision, where a receiver gives DOPs only.
inline constexpr double kMavlinkUserRangeErrorM = 2.5;

struct MavlinkGnssOptions {
  double latency_s = 0.0;  // a fix is this much older than its arrival
  // 1-sigma accuracy given to a fix whose message states none (GLOBAL_POSITION_INT; a GPS_RAW_INT
  // without h_acc / v_acc or DOPs).
  double stated_horizontal_accuracy_m = 3.0;
  double stated_vertical_accuracy_m = 6.0;
  int system_id = 0;  // only frames from this MAVLink system (0: any)
  // MAVLink 2 message signing: only frames signed with this key are read (none: signatures are
  // not checked).
  std::optional<std::array<uint8_t, 32>> signing_key;
  // The newest signature timestamp an earlier decoder accepted (MAVLink's 10 us units since
  // 2015): every stream, new to this decoder, is held to it as to the newest of its own.
  uint64_t newest_signed_before = 0;
};

struct MavlinkGnssCounts {
  int64_t frames = 0;         // frames whose CRC checked out (any message)
  int64_t damaged = 0;        // frames of a known message whose CRC or length did not
  int64_t bytes_skipped = 0;  // bytes outside any good frame
  int64_t fixes = 0;          // fixes returned
  int64_t refused = 0;        // position messages without a usable fix (no lock, impossible values)
  // With a signing key: frames refused for want of a signature (unsigned, or MAVLink 1), for a
  // signature that does not check out, and for a timestamp no newer than its stream's last.
  int64_t unsigned_frames = 0;
  int64_t bad_signatures = 0;
  int64_t replayed = 0;
};

class MavlinkGnssDecoder {
 public:
  explicit MavlinkGnssDecoder(MavlinkGnssOptions options = {});

  // Feeds the next bytes of the stream, received at `arrived_t_ns`; returns the fixes they
  // completed, in order. Never throws for any input; holds at most one frame's bytes between calls.
  std::vector<GnssFix> Feed(const uint8_t* data, size_t size, int64_t arrived_t_ns);
  // The same for one UDP datagram, which holds whole frames: none continues past its end (a
  // damaged length never holds back the frames after it), and nothing is kept for the next one.
  std::vector<GnssFix> FeedDatagram(const uint8_t* data, size_t size, int64_t arrived_t_ns);

  const MavlinkGnssCounts& counts() const { return counts_; }
  bool checks_signatures() const { return options_.signing_key.has_value(); }
  // The newest signature timestamp accepted (or given as newest_signed_before).
  uint64_t newest_signed() const { return newest_signed_; }

 private:
  // Reads the frames in pending_; `whole`: pending_ is all there is (a datagram).
  std::vector<GnssFix> Parse(int64_t arrived_t_ns, bool whole);
  // A checked frame's payload (zero-filled to the longest the message has): a fix or nothing.
  void Decode(uint32_t id, int system, const uint8_t* payload, int64_t arrived_t_ns, std::vector<GnssFix>* fixes);

  MavlinkGnssOptions options_;
  MavlinkGnssCounts counts_;
  std::vector<uint8_t> pending_;
  // Checks a signed frame's signature and timestamp (`frame_size` bytes from its marker, the
  // signature's 13 at the end); counts a refusal. Never throws.
  bool SignatureAccepted(const uint8_t* frame, size_t frame_size);

  std::vector<int> systems_with_raw_fixes_;
  std::map<int, ReceiverClock> clocks_;  // per system
  // The newest signature timestamp accepted per (system, component, link).
  std::map<std::tuple<int, int, int>, uint64_t> last_signed_;
  uint64_t newest_signed_ = 0;
  int64_t last_t_ns_ = INT64_MIN / 2;
};

// X.25 CRC (CRC-16/MCRF4XX) as MAVLink accumulates it, from `crc` on.
uint16_t MavlinkCrc(const uint8_t* data, size_t size, uint16_t crc = 0xFFFF);

// A MAVLink 2 frame of message `message_id` with `payload` (for tests and simulators: its trailing
// zero bytes are trimmed, as senders do), or MAVLink 1 where `version` is 1.
struct MavlinkFrameHeader {
  int version = 2;
  uint8_t sequence = 0, system_id = 1, component_id = 1;
  // MAVLink 2 only: signed with this key, on this link, at this timestamp (10 us units since
  // 2015-01-01, as MAVLink counts them).
  std::optional<std::array<uint8_t, 32>> signing_key;
  uint8_t link_id = 0;
  uint64_t signing_timestamp = 0;
};
std::vector<uint8_t> EncodeMavlinkFrame(uint32_t message_id, std::vector<uint8_t> payload,
                                        const MavlinkFrameHeader& header = {});

// GPS_RAW_INT and GLOBAL_POSITION_INT payloads as MAVLink lays them out (little-endian, fields
// ordered by size), for tests and simulators.
struct MavlinkGpsRawInt {
  uint64_t time_usec = 0;
  int32_t lat_e7 = 0, lon_e7 = 0, alt_mm = 0;
  uint16_t eph = UINT16_MAX, epv = UINT16_MAX, vel = UINT16_MAX, cog = UINT16_MAX;
  uint8_t fix_type = 0, satellites_visible = 255;
  int32_t alt_ellipsoid_mm = 0;
  uint32_t h_acc_mm = 0, v_acc_mm = 0, vel_acc = 0, hdg_acc = 0;
  uint16_t yaw = 0;
};
std::vector<uint8_t> MavlinkPayload(const MavlinkGpsRawInt& message);
struct MavlinkGlobalPositionInt {
  uint32_t time_boot_ms = 0;
  int32_t lat_e7 = 0, lon_e7 = 0, alt_mm = 0, relative_alt_mm = 0;
  int16_t vx = 0, vy = 0, vz = 0;
  uint16_t hdg = UINT16_MAX;
};
std::vector<uint8_t> MavlinkPayload(const MavlinkGlobalPositionInt& message);

inline constexpr uint32_t kMavlinkGpsRawInt = 24;
inline constexpr uint32_t kMavlinkGlobalPositionInt = 33;

}  // namespace stitch
