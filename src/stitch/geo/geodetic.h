#pragma once
// Places on Earth: WGS84 latitude, longitude and ellipsoidal height, and the local
// east-north-up (ENU) frame a geo-referenced map is expressed in (a plane tangent to the
// ellipsoid at an origin; GeographicLib's LocalCartesian does the geodesy).

#include <memory>
#include <string>

#include <Eigen/Core>

namespace GeographicLib {
class LocalCartesian;
}

namespace stitch {

// WGS84 (EPSG:4979): degrees north and east, metres above the ellipsoid.
struct GeodeticPoint {
  double latitude_deg = 0.0;
  double longitude_deg = 0.0;
  double height_m = 0.0;
};

// Why `point` is no place on Earth (latitude outside [-90, 90], longitude outside [-180, 180],
// a height outside [-12 km, 100 km], or a value that is not finite); empty when it is one.
std::string WhyNotOnEarth(const GeodeticPoint& point);

// A UTM zone (1-60) and hemisphere, and its EPSG code (WGS 84 / UTM: 326zz north, 327zz south).
struct UtmZone {
  int zone = 0;
  bool north = true;
  int epsg() const { return (north ? 32600 : 32700) + zone; }
};
// The zone `point` lies in (the standard one; UPS near the poles, |latitude| > 84, is not
// handled: throws stitch::Error).
UtmZone UtmZoneOf(const GeodeticPoint& point);
// `point`'s easting and northing in metres, in `zone` (a neighbouring zone's point is extended
// into it, as a map crossing a zone border is kept in one).
Eigen::Vector2d ToUtm(const GeodeticPoint& point, const UtmZone& zone);

// The local tangent plane at `origin`: x east, y north, z up, in metres; the origin at 0.
// Accurate to the millimetre within tens of kilometres of the origin (the frame is Cartesian,
// not a projection: far from the origin "up" tilts away from the local vertical).
class LocalTangentPlane {
 public:
  // Throws stitch::Error when the origin is no place on Earth.
  explicit LocalTangentPlane(const GeodeticPoint& origin);

  const GeodeticPoint& origin() const { return origin_; }
  Eigen::Vector3d ToEnu(const GeodeticPoint& point) const;
  GeodeticPoint ToGeodetic(const Eigen::Vector3d& enu) const;

 private:
  GeodeticPoint origin_;
  std::shared_ptr<const GeographicLib::LocalCartesian> frame_;  // immutable, shared by copies
};

}  // namespace stitch
