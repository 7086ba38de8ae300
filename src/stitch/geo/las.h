#pragma once
// Point clouds in LAS 1.2 (ASPRS), the format surveyors' tools open (CloudCompare, QGIS, PDAL,
// LAStools): point data format 2 (x, y, z and colour), coordinates stored to the millimetre, and
// the coordinate reference system as a GeoTIFF key directory (a projected CRS by its EPSG code:
// WGS 84 / UTM), heights above the WGS84 ellipsoid.

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace stitch {

struct LasPoint {
  Eigen::Vector3d position = Eigen::Vector3d::Zero();  // metres in the CRS
  uint8_t red = 200, green = 200, blue = 200;
};

struct LasCloud {
  int epsg = 0;  // the projected CRS (0: none stated)
  std::string generating_software = "stitch";
  std::vector<LasPoint> points;
};

// Written atomically; throws stitch::Error naming the file when it cannot be written, or when a
// coordinate is not finite or does not fit the millimetre grid around the cloud (a cloud more than
// 2,000 km across).
void WriteLas(const std::string& path, const LasCloud& cloud);
// Reads what WriteLas writes (point format 2 and its key directory; for tests and tools); throws
// stitch::Error naming the file for anything else.
LasCloud ReadLas(const std::string& path);

}  // namespace stitch
