#include "stitch/geo/geodetic.h"

#include <cmath>

#include <GeographicLib/LocalCartesian.hpp>
#include <GeographicLib/UTMUPS.hpp>

#include "stitch/util/error.h"

namespace stitch {

std::string WhyNotOnEarth(const GeodeticPoint& point) {
  if (!std::isfinite(point.latitude_deg) || !std::isfinite(point.longitude_deg) || !std::isfinite(point.height_m)) {
    return "a coordinate is not a finite number";
  }
  if (std::abs(point.latitude_deg) > 90.0) return Str() << "latitude " << point.latitude_deg << " is outside [-90, 90]";
  if (std::abs(point.longitude_deg) > 180.0) {
    return Str() << "longitude " << point.longitude_deg << " is outside [-180, 180]";
  }
  if (point.height_m < -12000.0 || point.height_m > 100000.0) {
    return Str() << "height " << point.height_m << " m is outside [-12 km, 100 km]";
  }
  return "";
}

UtmZone UtmZoneOf(const GeodeticPoint& point) {
  if (const std::string why = WhyNotOnEarth(point); !why.empty()) throw Error("no UTM zone: " + why);
  if (std::abs(point.latitude_deg) > 84.0)
    throw Error("no UTM zone beyond 84 degrees of latitude (UPS is not written)");
  UtmZone zone;
  zone.zone = GeographicLib::UTMUPS::StandardZone(point.latitude_deg, point.longitude_deg);
  zone.north = point.latitude_deg >= 0;
  return zone;
}

Eigen::Vector2d ToUtm(const GeodeticPoint& point, const UtmZone& zone) {
  int used_zone = 0;
  bool north = true;
  Eigen::Vector2d utm;
  GeographicLib::UTMUPS::Forward(point.latitude_deg, point.longitude_deg, used_zone, north, utm.x(), utm.y(),
                                 zone.zone);
  // Forward gives the northing of the point's own hemisphere: held to the zone's (a map across
  // the equator stays in one frame).
  if (north != zone.north) utm.y() += zone.north ? -10'000'000.0 : 10'000'000.0;
  return utm;
}

LocalTangentPlane::LocalTangentPlane(const GeodeticPoint& origin) : origin_(origin) {
  if (const std::string why = WhyNotOnEarth(origin); !why.empty()) {
    throw Error("the local frame's origin is no place on Earth: " + why);
  }
  frame_ =
      std::make_shared<const GeographicLib::LocalCartesian>(origin.latitude_deg, origin.longitude_deg, origin.height_m);
}

Eigen::Vector3d LocalTangentPlane::ToEnu(const GeodeticPoint& point) const {
  Eigen::Vector3d enu;
  frame_->Forward(point.latitude_deg, point.longitude_deg, point.height_m, enu.x(), enu.y(), enu.z());
  return enu;
}

GeodeticPoint LocalTangentPlane::ToGeodetic(const Eigen::Vector3d& enu) const {
  GeodeticPoint point;
  frame_->Reverse(enu.x(), enu.y(), enu.z(), point.latitude_deg, point.longitude_deg, point.height_m);
  return point;
}

}  // namespace stitch
