#include "stitch/geo/las.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <ctime>
#include <fstream>
#include <iterator>

#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace stitch {
namespace {

constexpr uint16_t kHeaderSize = 227;
constexpr uint16_t kVlrHeaderSize = 54;
constexpr uint8_t kPointFormat = 2;
constexpr uint16_t kPointSize = 26;
constexpr double kScale = 0.001;  // millimetres
constexpr uint16_t kGeoKeyDirectoryRecord = 34735;
constexpr uint16_t kProjectedCrsKey = 3072, kModelTypeKey = 1024, kRasterTypeKey = 1025, kLinearUnitsKey = 3076,
                   kVerticalCrsKey = 4096, kVerticalUnitsKey = 4099;
constexpr uint16_t kMetre = 9001, kEllipsoidalWgs84 = 5030;

template <class T>
void Put(std::string* bytes, T value) {
  char raw[sizeof(T)];
  std::memcpy(raw, &value, sizeof(T));  // LAS is little-endian, as is every target here
  bytes->append(raw, sizeof(T));
}

void PutText(std::string* bytes, const std::string& text, size_t size) {
  std::string field = text.substr(0, size);
  field.resize(size, '\0');
  bytes->append(field);
}

template <class T>
T Get(const std::string& bytes, size_t offset) {
  T value;
  std::memcpy(&value, bytes.data() + offset, sizeof(T));
  return value;
}

}  // namespace

void WriteLas(const std::string& path, const LasCloud& cloud) {
  Eigen::Vector3d low = Eigen::Vector3d::Constant(0), high = Eigen::Vector3d::Constant(0);
  if (!cloud.points.empty()) {
    low = high = cloud.points.front().position;
    for (const LasPoint& p : cloud.points) {
      if (!p.position.allFinite()) throw Error(path + ": a point's coordinate is not finite");
      low = low.cwiseMin(p.position);
      high = high.cwiseMax(p.position);
    }
  }
  // Offsets at whole kilometres below the cloud: every point's integer fits an int32 of millimetres.
  const Eigen::Vector3d offset = (low / 1000.0).array().floor() * 1000.0;
  if (((high - offset) / kScale).maxCoeff() > 2.0e9) throw Error(path + ": the cloud is too wide for LAS's grid");

  // The CRS: a GeoTIFF key directory (version 1.1.0), its keys in ascending order.
  std::vector<uint16_t> keys = {1, 1, 0, 0};
  const auto key = [&](uint16_t id, uint16_t value) { keys.insert(keys.end(), {id, 0, 1, value}); };
  if (cloud.epsg > 0) {
    key(kModelTypeKey, 1);   // projected
    key(kRasterTypeKey, 1);  // pixel is area
    key(kProjectedCrsKey, static_cast<uint16_t>(cloud.epsg));
    key(kLinearUnitsKey, kMetre);
    key(kVerticalCrsKey, kEllipsoidalWgs84);
    key(kVerticalUnitsKey, kMetre);
    keys[3] = static_cast<uint16_t>(keys.size() / 4 - 1);
  }
  const bool has_crs = cloud.epsg > 0;
  const uint32_t vlr_bytes = has_crs ? kVlrHeaderSize + static_cast<uint32_t>(2 * keys.size()) : 0;

  std::string bytes;
  bytes.reserve(kHeaderSize + vlr_bytes + kPointSize * cloud.points.size());
  bytes.append("LASF", 4);
  Put<uint16_t>(&bytes, 0);  // file source id
  Put<uint16_t>(&bytes, 0);  // global encoding: GPS week time (no times here)
  bytes.append(16, '\0');    // project GUID
  Put<uint8_t>(&bytes, 1);
  Put<uint8_t>(&bytes, 2);  // version 1.2
  PutText(&bytes, "stitch monocular SLAM", 32);
  PutText(&bytes, cloud.generating_software, 32);
  const std::time_t now = std::time(nullptr);
  std::tm utc{};
  gmtime_r(&now, &utc);
  Put<uint16_t>(&bytes, static_cast<uint16_t>(utc.tm_yday + 1));
  Put<uint16_t>(&bytes, static_cast<uint16_t>(utc.tm_year + 1900));
  Put<uint16_t>(&bytes, kHeaderSize);
  Put<uint32_t>(&bytes, kHeaderSize + vlr_bytes);  // offset to the points
  Put<uint32_t>(&bytes, has_crs ? 1 : 0);          // variable length records
  Put<uint8_t>(&bytes, kPointFormat);
  Put<uint16_t>(&bytes, kPointSize);
  Put<uint32_t>(&bytes, static_cast<uint32_t>(cloud.points.size()));
  Put<uint32_t>(&bytes, static_cast<uint32_t>(cloud.points.size()));  // all first returns
  for (int i = 0; i < 4; ++i) Put<uint32_t>(&bytes, 0);
  for (int i = 0; i < 3; ++i) Put<double>(&bytes, kScale);
  for (int i = 0; i < 3; ++i) Put<double>(&bytes, offset[i]);
  for (int i = 0; i < 3; ++i) {
    Put<double>(&bytes, high[i]);
    Put<double>(&bytes, low[i]);
  }
  if (bytes.size() != kHeaderSize) throw Error(path + ": LAS header of the wrong size (a bug)");
  if (has_crs) {
    Put<uint16_t>(&bytes, 0);  // reserved
    PutText(&bytes, "LASF_Projection", 16);
    Put<uint16_t>(&bytes, kGeoKeyDirectoryRecord);
    Put<uint16_t>(&bytes, static_cast<uint16_t>(2 * keys.size()));
    PutText(&bytes, "GeoKeyDirectoryTag", 32);
    for (uint16_t k : keys) Put<uint16_t>(&bytes, k);
  }
  for (const LasPoint& p : cloud.points) {
    for (int i = 0; i < 3; ++i)
      Put<int32_t>(&bytes, static_cast<int32_t>(std::llround((p.position[i] - offset[i]) / kScale)));
    Put<uint16_t>(&bytes, 0);    // intensity
    Put<uint8_t>(&bytes, 0x09);  // return 1 of 1
    Put<uint8_t>(&bytes, 0);     // classification: created, never classified
    Put<int8_t>(&bytes, 0);      // scan angle
    Put<uint8_t>(&bytes, 0);     // user data
    Put<uint16_t>(&bytes, 0);    // point source id
    for (uint8_t c : {p.red, p.green, p.blue}) Put<uint16_t>(&bytes, static_cast<uint16_t>(c * 257));
  }
  WriteFileAtomically(path, bytes);
}

LasCloud ReadLas(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(path + ": cannot open");
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (bytes.size() < kHeaderSize || bytes.compare(0, 4, "LASF") != 0) throw Error(path + ": not a LAS file");
  if (Get<uint8_t>(bytes, 24) != 1 || Get<uint8_t>(bytes, 25) != 2) throw Error(path + ": not LAS 1.2");
  const uint32_t point_offset = Get<uint32_t>(bytes, 96), vlrs = Get<uint32_t>(bytes, 100);
  if (Get<uint8_t>(bytes, 104) != kPointFormat || Get<uint16_t>(bytes, 105) != kPointSize)
    throw Error(path + ": not point data format 2");
  const uint32_t count = Get<uint32_t>(bytes, 107);
  if (point_offset > bytes.size() || (bytes.size() - point_offset) / kPointSize < count)
    throw Error(path + ": cut short");
  double scale[3], offset[3];
  for (int i = 0; i < 3; ++i) {
    scale[i] = Get<double>(bytes, 131 + 8 * i);
    offset[i] = Get<double>(bytes, 155 + 8 * i);
  }
  LasCloud cloud;
  cloud.generating_software = std::string(bytes.data() + 58, strnlen(bytes.data() + 58, 32));
  size_t at = Get<uint16_t>(bytes, 94);
  for (uint32_t v = 0; v < vlrs && at + kVlrHeaderSize <= point_offset; ++v) {
    const uint16_t record = Get<uint16_t>(bytes, at + 18), length = Get<uint16_t>(bytes, at + 20);
    const size_t body = at + kVlrHeaderSize;
    if (body + length > point_offset) throw Error(path + ": a variable length record runs into the points");
    if (record == kGeoKeyDirectoryRecord && length >= 8) {
      const uint16_t keys = Get<uint16_t>(bytes, body + 6);
      for (uint16_t k = 1; k <= keys && 8u * (k + 1) <= length; ++k) {
        if (Get<uint16_t>(bytes, body + 8 * k) == kProjectedCrsKey) cloud.epsg = Get<uint16_t>(bytes, body + 8 * k + 6);
      }
    }
    at = body + length;
  }
  for (uint32_t i = 0; i < count; ++i) {
    const size_t p = point_offset + static_cast<size_t>(i) * kPointSize;
    LasPoint point;
    for (int k = 0; k < 3; ++k) point.position[k] = Get<int32_t>(bytes, p + 4 * k) * scale[k] + offset[k];
    point.red = static_cast<uint8_t>(Get<uint16_t>(bytes, p + 20) / 257);
    point.green = static_cast<uint8_t>(Get<uint16_t>(bytes, p + 22) / 257);
    point.blue = static_cast<uint8_t>(Get<uint16_t>(bytes, p + 24) / 257);
    cloud.points.push_back(point);
  }
  return cloud;
}

}  // namespace stitch
