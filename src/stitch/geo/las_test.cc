#include "stitch/geo/las.h"

#include <fstream>

#include <gtest/gtest.h>

#include "stitch/geo/geodetic.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

TEST(Las, WritesWhatItReadsBackToTheMillimetreWithItsCrs) {
  LasCloud cloud;
  cloud.epsg = 32632;
  for (int i = 0; i < 100; ++i) {
    LasPoint p;
    p.position = Eigen::Vector3d(648'123.4567 + i, 5'318'456.7891 - 2.5 * i, 612.3456 + 0.01 * i);
    p.red = static_cast<uint8_t>(i);
    p.blue = 255;
    cloud.points.push_back(p);
  }
  testing::TempDir dir;
  const std::string path = dir / "cloud.las";
  WriteLas(path, cloud);
  // The fixed parts a reader checks first: signature, version, header size, point format.
  std::ifstream in(path, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(bytes.substr(0, 4), "LASF");
  EXPECT_EQ(bytes[24], 1);
  EXPECT_EQ(bytes[25], 2);
  EXPECT_EQ(bytes.size(), 227u + 54u + 2u * 4u * 7u + 26u * 100u) << "header, the key directory (6 keys), points";
  const LasCloud read = ReadLas(path);
  EXPECT_EQ(read.epsg, 32632);
  ASSERT_EQ(read.points.size(), 100u);
  for (size_t i = 0; i < read.points.size(); ++i) {
    EXPECT_LT((read.points[i].position - cloud.points[i].position).cwiseAbs().maxCoeff(), 0.0006) << i;
    EXPECT_EQ(read.points[i].red, cloud.points[i].red);
    EXPECT_EQ(read.points[i].blue, 255);
  }
  // No CRS: no key directory. No points: a valid empty file.
  cloud.epsg = 0;
  cloud.points.resize(1);
  WriteLas(dir / "plain.las", cloud);
  EXPECT_EQ(ReadLas(dir / "plain.las").epsg, 0);
  WriteLas(dir / "empty.las", LasCloud());
  EXPECT_TRUE(ReadLas(dir / "empty.las").points.empty());
}

TEST(Las, RefusesWhatItCannotWriteOrRead) {
  testing::TempDir dir;
  LasCloud cloud;
  cloud.points.resize(2);
  cloud.points[1].position.x() = std::nan("");
  EXPECT_THROW(WriteLas(dir / "nan.las", cloud), Error);
  cloud.points[1].position.x() = 3e9;  // 3,000 km from the first
  EXPECT_THROW(WriteLas(dir / "wide.las", cloud), Error);
  std::ofstream(dir / "text.las") << "not LAS";
  EXPECT_THROW(ReadLas(dir / "text.las"), Error);
  cloud.points[1].position.x() = 10;
  WriteLas(dir / "cut.las", cloud);
  std::filesystem::resize_file(dir / "cut.las", 240);
  EXPECT_THROW(ReadLas(dir / "cut.las"), Error);
}

TEST(Utm, PlacesPointsInTheirZone) {
  // Zurich: zone 32 north; its UTM coordinates as surveyors know them (about 465 km E, 5 247 km N).
  const GeodeticPoint zurich{47.3769, 8.5417, 408};
  const UtmZone zone = UtmZoneOf(zurich);
  EXPECT_EQ(zone.zone, 32);
  EXPECT_TRUE(zone.north);
  EXPECT_EQ(zone.epsg(), 32632);
  const Eigen::Vector2d utm = ToUtm(zurich, zone);
  EXPECT_NEAR(utm.x(), 465'200, 1'000);
  EXPECT_NEAR(utm.y(), 5'247'000, 2'000);
  // Sydney: zone 56 south (EPSG 32756).
  EXPECT_EQ(UtmZoneOf({-33.8688, 151.2093, 0}).epsg(), 32756);
  // A point just across the zone border is kept in the given zone, continuous.
  const Eigen::Vector2d across = ToUtm({47.3769, 9.0001, 408}, zone);
  const Eigen::Vector2d before = ToUtm({47.3769, 8.9999, 408}, zone);
  EXPECT_LT((across - before).norm(), 20.0);
  EXPECT_THROW(UtmZoneOf({85.0, 0.0, 0}), Error);
}

}  // namespace
}  // namespace stitch
