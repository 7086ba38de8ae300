#pragma once
// Fixes of the aircraft's GNSS receiver, and gnss.csv, the plain file they travel in beside a
// dataset (a DJI .SRT, EXIF tags or a receiver's stream are read into the same fixes).
//
// gnss.csv: '#' comments, then the header line and one fix a line, in time order:
//   t_ns,latitude_deg,longitude_deg,height_m,horizontal_accuracy_m,vertical_accuracy_m,fix
// t_ns on the camera's clock (the calibration's time offset aside); height above the WGS84
// ellipsoid; the accuracies are the receiver's own 1-sigma claims; fix is none, 2d, 3d, dgps,
// rtk_float or rtk_fixed. Two comments are read: "# source: TEXT" and, where a dataset's ground
// truth is in the local ENU frame of a known point (the synthetic flight's),
// "# ground_truth_enu_origin: LAT LON HEIGHT".

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "stitch/geo/geodetic.h"

namespace stitch {

enum class GnssFixType { kNone = 0, k2d, k3d, kDgps, kRtkFloat, kRtkFixed };
const char* GnssFixTypeName(GnssFixType type);  // "none", "2d", ...

struct GnssFix {
  int64_t t_ns = 0;
  GeodeticPoint position;
  double horizontal_accuracy_m = 0.0;  // 1 sigma, per horizontal axis
  double vertical_accuracy_m = 0.0;    // 1 sigma
  GnssFixType type = GnssFixType::k3d;
  // The source states the height above mean sea level (DJI, EXIF, MAVLink's altitudes), not the
  // ellipsoid: HeightsAboveEllipsoid (geoid.h) raises it by the geoid's height.
  bool height_above_msl = false;

  bool usable() const { return type != GnssFixType::kNone; }
};

struct GnssTrack {
  std::string source;                                    // e.g. "synthetic receiver", "gpsd"
  std::vector<GnssFix> fixes;                            // in time order
  std::optional<GeodeticPoint> ground_truth_enu_origin;  // the ground truth's frame is ENU at this point
};

// Why `fix` cannot be used (no place on Earth, an accuracy that is not a positive finite number
// of metres); empty when it can. A fix of type none may have any position.
std::string WhyNotAFix(const GnssFix& fix);

// Throws stitch::Error naming the file and line for a missing or wrong header, a malformed or
// impossible fix, or times that do not increase.
GnssTrack ReadGnssCsv(const std::string& path);
// Written atomically; throws stitch::Error naming the file.
void WriteGnssCsv(const std::string& path, const GnssTrack& track);

// The fixes' ENU positions in `plane`, for those of them that are usable.
struct EnuFix {
  int64_t t_ns = 0;
  Eigen::Vector3d enu = Eigen::Vector3d::Zero();
  double horizontal_sigma_m = 1.0;
  double vertical_sigma_m = 1.0;
};
std::vector<EnuFix> ToEnu(const std::vector<GnssFix>& fixes, const LocalTangentPlane& plane);

}  // namespace stitch
