#pragma once
// A mosaic as a GeoTIFF (GDAL's GTiff driver): red, green, blue and an alpha band (where the
// mosaic is drawn), 256-pixel tiles, DEFLATE compression and overviews down to a tile, placed by
// its corner and pixel size in a CRS named by its EPSG code or PROJ's words, or in a local frame
// (no CRS).

#include <map>
#include <string>

#include <opencv2/core.hpp>

namespace stitch {

struct GeoTiffImage {
  cv::Mat colour;    // CV_8UC3, BGR
  cv::Mat coverage;  // CV_8UC1: 255 where drawn (the alpha band)
  // The raster's top-left corner (of its first pixel) and its pixel size, in the CRS's units:
  // pixel (col, row) covers x in west + [col, col + 1] * pixel_size, y in north - [row, row + 1] *
  // pixel_size.
  double west = 0.0, north = 0.0, pixel_size = 1.0;
  int epsg = 0;                                 // 0: `crs`, or a local frame where that is empty
  std::string crs;                              // where epsg is 0: a CRS in PROJ's words ("+proj=ortho ...")
  int deflate_level = 6;                        // 1 (fastest) to 9 (smallest): a file written again and again wants 1
  std::map<std::string, std::string> metadata;  // written as the dataset's metadata items
};

// Writes `image` to `path` (a temporary file renamed into place). Throws stitch::Error naming the
// file when it cannot be written or the image is not as described.
void WriteGeoTiff(const std::string& path, const GeoTiffImage& image);

// What a GeoTIFF says of itself (GDAL reading it back).
struct GeoTiffInfo {
  int width = 0, height = 0, bands = 0;
  int epsg = 0;     // its CRS's EPSG code where it has one
  std::string crs;  // its CRS in PROJ's words where it has one
  double geo_transform[6] = {0, 1, 0, 0, 0, 1};
  int overviews = 0;  // of its first band
  std::map<std::string, std::string> metadata;
};
// Throws stitch::Error when `path` is not a raster GDAL reads.
GeoTiffInfo ReadGeoTiffInfo(const std::string& path);
// The GeoTIFF's bands as BGR and alpha (GDAL reading it back). Throws stitch::Error.
GeoTiffImage ReadGeoTiff(const std::string& path);

}  // namespace stitch
