#pragma once
// The synthetic aircraft's GNSS receiver: fixes of the true camera positions at a chosen rate,
// with noise, dropouts, multipath jumps and a constant offset from a chosen time on. The
// synthetic world's frame is the local ENU frame at `origin_*` (x east along the first strip,
// y north, z up), so the flight's ground truth is where the fixes say.

#include <cstdint>
#include <string>
#include <vector>

#include "stitch/geo/gnss_fix.h"
#include "stitch/io/trajectory.h"

namespace stitch {

struct GnssReceiverOptions {
  double rate_hz = 5.0;               // fixes per second (0: no receiver)
  double horizontal_noise_m = 2.0;    // 1 sigma per horizontal axis, white; also the accuracy each fix states
  double vertical_noise_m = 3.0;      // 1 sigma, white
  double origin_latitude_deg = 48.0;  // where the synthetic world's origin is on Earth (WGS84)
  double origin_longitude_deg = 11.0;
  double origin_height_m = 600.0;  // above the ellipsoid
  std::string dropouts;            // "START_S:LENGTH_S,...": no fix in those spans (the flight's clock: frame 0 at 0 s)
  std::string jumps;               // "START_S:LENGTH_S:METRES,...": fixes displaced north (multipath)
  double offset_m = 0.0;           // every fix from offset_from_s on displaced east (a spoofed or shifted receiver)
  double offset_from_s = 0.0;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("rate_hz", rate_hz, "GNSS fixes per second (0: the aircraft has no receiver)");
    v("horizontal_noise_m", horizontal_noise_m,
      "white noise of a fix per horizontal axis, 1 sigma, metres (also the accuracy each fix states)");
    v("vertical_noise_m", vertical_noise_m, "white noise of a fix's height, 1 sigma, metres");
    v("origin_latitude_deg", origin_latitude_deg, "the synthetic world's origin on Earth: latitude, WGS84 degrees");
    v("origin_longitude_deg", origin_longitude_deg, "the origin's longitude, WGS84 degrees");
    v("origin_height_m", origin_height_m, "the origin's height above the WGS84 ellipsoid, metres");
    v("dropouts", dropouts, "spans without a fix, START_S:LENGTH_S,... seconds on the flight's clock (frame 0 at 0 s)");
    v("jumps", jumps, "spans of fixes displaced north (multipath), START_S:LENGTH_S:METRES,...");
    v("offset_m", offset_m, "every fix from offset_from_s on displaced east by this many metres (0: none)");
    v("offset_from_s", offset_from_s, "the time offset_m begins, seconds on the flight's clock");
  }
  bool Check(std::string* why) const;
};

// The receiver's fixes over the span of `ground_truth` (world_from_cam in the world's frame), at
// every 1 / rate_hz s of its clock, deterministic from `seed` and the fix's time: a part of the
// flight (--start-frame, --max-frames) has the whole flight's fixes over that part. Empty when rate_hz is 0. Throws
// stitch::Error on invalid options.
GnssTrack SimulateGnssReceiver(const Trajectory& ground_truth, const GnssReceiverOptions& options, uint64_t seed);

}  // namespace stitch
