#include "stitch/mosaic/geotiff.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <vector>

#include <cpl_conv.h>
#include <cpl_string.h>
#include <gdal_priv.h>
#include <ogr_spatialref.h>

#include "stitch/util/error.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

struct DatasetCloser {
  void operator()(GDALDataset* dataset) const { GDALClose(dataset); }
};
using DatasetPtr = std::unique_ptr<GDALDataset, DatasetCloser>;

std::string LastGdalError() {
  const char* text = CPLGetLastErrorMsg();
  return text && *text ? text : "GDAL gave no reason";
}

// GDAL's errors are taken from CPLGetLastErrorMsg into ours, not printed.
class QuietGdal {
 public:
  QuietGdal() { CPLPushErrorHandler(CPLQuietErrorHandler); }
  ~QuietGdal() { CPLPopErrorHandler(); }
  QuietGdal(const QuietGdal&) = delete;
  QuietGdal& operator=(const QuietGdal&) = delete;
};

}  // namespace

void WriteGeoTiff(const std::string& path, const GeoTiffImage& image) {
  if (image.colour.empty() || image.colour.type() != CV_8UC3) throw Error(path + ": the mosaic must be 8-bit BGR");
  if (image.coverage.type() != CV_8UC1 || image.coverage.size() != image.colour.size()) {
    throw Error(path + ": the mosaic's coverage must be 8-bit and of its size");
  }
  if (!(image.pixel_size > 0)) throw Error(path + ": the pixel size must be positive");
  const QuietGdal quiet;
  GDALAllRegister();
  GDALDriver* driver = GetGDALDriverManager()->GetDriverByName("GTiff");
  if (!driver) throw Error(path + ": GDAL has no GTiff driver");
  const std::string temporary = path + ".partial";
  const int width = image.colour.cols, height = image.colour.rows;
  char** options = nullptr;
  options = CSLSetNameValue(options, "TILED", "YES");
  options = CSLSetNameValue(options, "BLOCKXSIZE", "256");
  options = CSLSetNameValue(options, "BLOCKYSIZE", "256");
  options = CSLSetNameValue(options, "COMPRESS", "DEFLATE");
  options = CSLSetNameValue(options, "ZLEVEL", std::to_string(std::clamp(image.deflate_level, 1, 9)).c_str());
  options = CSLSetNameValue(options, "PHOTOMETRIC", "RGB");
  options = CSLSetNameValue(options, "ALPHA", "YES");
  options = CSLSetNameValue(options, "BIGTIFF", "IF_SAFER");
  DatasetPtr dataset(driver->Create(temporary.c_str(), width, height, 4, GDT_Byte, options));
  CSLDestroy(options);
  if (!dataset) throw Error(path + ": cannot be written: " + LastGdalError());
  try {
    double transform[6] = {image.west, image.pixel_size, 0.0, image.north, 0.0, -image.pixel_size};
    if (dataset->SetGeoTransform(transform) != CE_None) throw Error("no geotransform: " + LastGdalError());
    if (image.epsg > 0) {
      OGRSpatialReference crs;
      if (crs.importFromEPSG(image.epsg) != OGRERR_NONE) {
        throw Error("EPSG:" + std::to_string(image.epsg) + " is not a CRS GDAL knows");
      }
      if (dataset->SetSpatialRef(&crs) != CE_None) throw Error("no CRS: " + LastGdalError());
    } else if (!image.crs.empty()) {
      OGRSpatialReference crs;
      if (crs.SetFromUserInput(image.crs.c_str()) != OGRERR_NONE) throw Error(image.crs + " is not a CRS GDAL knows");
      if (dataset->SetSpatialRef(&crs) != CE_None) throw Error("no CRS: " + LastGdalError());
    }
    for (const auto& [key, value] : image.metadata) dataset->SetMetadataItem(key.c_str(), value.c_str());
    std::vector<cv::Mat> planes;
    cv::split(image.colour, planes);  // B, G, R
    const cv::Mat bands[4] = {planes[2], planes[1], planes[0], image.coverage};
    for (int b = 0; b < 4; ++b) {
      const cv::Mat band = bands[b].isContinuous() ? bands[b] : bands[b].clone();
      if (dataset->GetRasterBand(b + 1)->RasterIO(GF_Write, 0, 0, width, height, const_cast<uchar*>(band.data), width,
                                                  height, GDT_Byte, 0, 0) != CE_None) {
        throw Error("band " + std::to_string(b + 1) + " not written: " + LastGdalError());
      }
    }
    dataset->GetRasterBand(1)->SetColorInterpretation(GCI_RedBand);
    dataset->GetRasterBand(2)->SetColorInterpretation(GCI_GreenBand);
    dataset->GetRasterBand(3)->SetColorInterpretation(GCI_BlueBand);
    dataset->GetRasterBand(4)->SetColorInterpretation(GCI_AlphaBand);
    // Overviews halving down to about a tile: what a GIS draws when zoomed out.
    std::vector<int> levels;
    for (int level = 2; width / level >= 256 || height / level >= 256; level *= 2) levels.push_back(level);
    if (!levels.empty() && dataset->BuildOverviews("AVERAGE", static_cast<int>(levels.size()), levels.data(), 0,
                                                   nullptr, nullptr, nullptr) != CE_None) {
      throw Error("no overviews: " + LastGdalError());
    }
    dataset.reset();  // flushes; a failure shows in the file it leaves
  } catch (const std::exception& e) {
    dataset.reset();
    std::error_code ignored;
    fs::remove(temporary, ignored);
    throw Error(path + ": " + e.what());
  }
  std::error_code error;
  fs::rename(temporary, path, error);
  if (error) {
    fs::remove(temporary, error);
    throw Error(path + ": cannot be written: " + error.message());
  }
}

GeoTiffInfo ReadGeoTiffInfo(const std::string& path) {
  const QuietGdal quiet;
  GDALAllRegister();
  DatasetPtr dataset(static_cast<GDALDataset*>(GDALOpen(path.c_str(), GA_ReadOnly)));
  if (!dataset) throw Error(path + ": not a raster GDAL reads: " + LastGdalError());
  GeoTiffInfo info;
  info.width = dataset->GetRasterXSize();
  info.height = dataset->GetRasterYSize();
  info.bands = dataset->GetRasterCount();
  dataset->GetGeoTransform(info.geo_transform);
  if (const OGRSpatialReference* crs = dataset->GetSpatialRef()) {
    const char* code = crs->GetAuthorityCode(nullptr);
    if (code) info.epsg = std::atoi(code);
    char* proj = nullptr;
    if (crs->exportToProj4(&proj) == OGRERR_NONE && proj) info.crs = proj;
    CPLFree(proj);
  }
  if (info.bands > 0) info.overviews = dataset->GetRasterBand(1)->GetOverviewCount();
  if (char** items = dataset->GetMetadata()) {
    for (char** item = items; *item; ++item) {
      char* key = nullptr;
      const char* value = CPLParseNameValue(*item, &key);
      if (key && value) info.metadata[key] = value;
      CPLFree(key);
    }
  }
  return info;
}

GeoTiffImage ReadGeoTiff(const std::string& path) {
  const GeoTiffInfo info = ReadGeoTiffInfo(path);
  if (info.bands != 4) throw Error(path + ": " + std::to_string(info.bands) + " bands, not a mosaic's 4");
  const QuietGdal quiet;
  GDALAllRegister();
  DatasetPtr dataset(static_cast<GDALDataset*>(GDALOpen(path.c_str(), GA_ReadOnly)));
  if (!dataset) throw Error(path + ": not a raster GDAL reads: " + LastGdalError());
  std::vector<cv::Mat> bands(4);
  for (int b = 0; b < 4; ++b) {
    bands[b] = cv::Mat(info.height, info.width, CV_8UC1);
    if (dataset->GetRasterBand(b + 1)->RasterIO(GF_Read, 0, 0, info.width, info.height, bands[b].data, info.width,
                                                info.height, GDT_Byte, 0, 0) != CE_None) {
      throw Error(path + ": band " + std::to_string(b + 1) + " not read: " + LastGdalError());
    }
  }
  GeoTiffImage image;
  cv::merge(std::vector<cv::Mat>{bands[2], bands[1], bands[0]}, image.colour);
  image.coverage = bands[3];
  image.west = info.geo_transform[0];
  image.north = info.geo_transform[3];
  image.pixel_size = info.geo_transform[1];
  image.epsg = info.epsg;
  if (image.epsg == 0) image.crs = info.crs;
  image.metadata = info.metadata;
  return image;
}

}  // namespace stitch
