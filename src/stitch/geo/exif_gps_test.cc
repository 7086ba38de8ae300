#include "stitch/geo/exif_gps.h"

#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "stitch/geo/exiv2.h"
#include "stitch/testing/temp_dir.h"

namespace stitch {
namespace {

STITCH_EXIV2_BEGIN

// A photo as a survey camera writes it: a JPEG whose EXIF holds `tags` (key, value as exiv2 reads
// it from text, e.g. "47/1 22/1 632/100").
std::string Photo(const std::filesystem::path& path, const std::vector<std::pair<std::string, std::string>>& tags,
                  const std::vector<std::pair<std::string, std::string>>& xmp = {}) {
  cv::imwrite(path.string(), cv::Mat(48, 64, CV_8UC1, cv::Scalar(128)));
  Exiv2::Image::AutoPtr image = Exiv2::ImageFactory::open(path.string());
  image->readMetadata();
  Exiv2::ExifData& exif = image->exifData();
  for (const auto& [key, value] : tags) exif[key] = value;
  if (!xmp.empty()) {
    Exiv2::XmpProperties::registerNs("http://www.dji.com/drone-dji/1.0/", "drone-dji");
    for (const auto& [key, value] : xmp) image->xmpData()[key] = value;
  }
  image->writeMetadata();
  return path.string();
}

STITCH_EXIV2_END

std::vector<std::pair<std::string, std::string>> ZurichTags() {
  return {{"Exif.GPSInfo.GPSLatitudeRef", "N"},  {"Exif.GPSInfo.GPSLatitude", "47/1 22/1 632/100"},
          {"Exif.GPSInfo.GPSLongitudeRef", "E"}, {"Exif.GPSInfo.GPSLongitude", "8/1 32/1 2059/100"},
          {"Exif.GPSInfo.GPSAltitudeRef", "0"},  {"Exif.GPSInfo.GPSAltitude", "459870/1000"}};
}

TEST(ExifGps, ReadsAPhotosPositionFromItsTags) {
  testing::TempDir dir;
  std::string why;
  const auto fix = ReadExifGps(Photo(dir / "a.jpg", ZurichTags()), &why);
  ASSERT_TRUE(fix) << why;
  EXPECT_NEAR(fix->position.latitude_deg, 47 + 22 / 60.0 + 6.32 / 3600, 1e-9);
  EXPECT_NEAR(fix->position.longitude_deg, 8 + 32 / 60.0 + 20.59 / 3600, 1e-9);
  EXPECT_NEAR(fix->position.height_m, 459.87, 1e-9);
  EXPECT_TRUE(fix->height_above_msl);
  EXPECT_EQ(fix->horizontal_accuracy_m, kExifHorizontalAccuracyM);
  EXPECT_EQ(fix->type, GnssFixType::k3d);

  // South, west, below sea level; the camera's stated positioning error.
  auto tags = ZurichTags();
  tags[0].second = "S";
  tags[2].second = "W";
  tags[4].second = "1";
  tags.push_back({"Exif.GPSInfo.GPSHPositioningError", "150/100"});
  const auto south = ReadExifGps(Photo(dir / "b.jpg", tags), &why);
  ASSERT_TRUE(south) << why;
  EXPECT_LT(south->position.latitude_deg, -47);
  EXPECT_LT(south->position.longitude_deg, -8);
  EXPECT_NEAR(south->position.height_m, -459.87, 1e-9);
  EXPECT_NEAR(south->horizontal_accuracy_m, 1.5, 1e-9);

  // A DJI RTK model's standard deviations.
  const auto rtk = ReadExifGps(Photo(dir / "c.jpg", ZurichTags(),
                                     {{"Xmp.drone-dji.RtkStdLat", "0.012"},
                                      {"Xmp.drone-dji.RtkStdLon", "0.015"},
                                      {"Xmp.drone-dji.RtkStdHgt", "0.031"}}),
                               &why);
  ASSERT_TRUE(rtk) << why;
  EXPECT_EQ(rtk->type, GnssFixType::kRtkFixed);
  EXPECT_NEAR(rtk->horizontal_accuracy_m, 0.015, 1e-12);
  EXPECT_NEAR(rtk->vertical_accuracy_m, 0.031, 1e-12);
}

// A DJI writes its gimbal's pitch into each photo's XMP: -90 is straight down, what a survey
// mission flies and what levels the map its fixes place (SourceCameraUpAxis).
TEST(ExifGps, ReadsTheGimbalsPitchAndWhetherThePhotosLookStraightDown) {
  testing::TempDir dir;
  const auto photo = [&](const std::string& name, const std::string& pitch) {
    return Photo(dir / name, ZurichTags(),
                 pitch.empty()
                     ? std::vector<std::pair<std::string, std::string>>{{"Xmp.drone-dji.RtkStdLat", "0.01"}}
                     : std::vector<std::pair<std::string, std::string>>{{"Xmp.drone-dji.GimbalPitchDegree", pitch}});
  };
  EXPECT_NEAR(ReadGimbalPitchDeg(photo("a.jpg", "-90.0")).value_or(0), -90.0, 1e-12);
  EXPECT_NEAR(ReadGimbalPitchDeg(photo("b.jpg", "-89.6")).value_or(0), -89.6, 1e-12);
  EXPECT_FALSE(ReadGimbalPitchDeg(photo("none.jpg", "")));
  EXPECT_FALSE(ReadGimbalPitchDeg(photo("text.jpg", "level"))) << "not a number";
  EXPECT_FALSE(ReadGimbalPitchDeg(photo("far.jpg", "-400"))) << "not an angle";
  { std::ofstream(dir / "broken.jpg") << "not a JPEG"; }
  EXPECT_FALSE(ReadGimbalPitchDeg(dir / "broken.jpg"));
  EXPECT_FALSE(ReadGimbalPitchDeg(dir / "missing.jpg"));

  const auto photos = [&](const std::vector<std::string>& names) {
    std::vector<ImageEntry> images;
    for (const std::string& name : names) images.push_back({static_cast<int64_t>(images.size()), dir / name});
    return images;
  };
  EXPECT_TRUE(PhotosStateANadirGimbal(photos({"a.jpg", "b.jpg", "none.jpg"})));
  photo("oblique.jpg", "-60.0");
  EXPECT_FALSE(PhotosStateANadirGimbal(photos({"a.jpg", "oblique.jpg"}))) << "one tilted photo among the first";
  EXPECT_FALSE(PhotosStateANadirGimbal(photos({"none.jpg", "broken.jpg"}))) << "none states a pitch";
  EXPECT_FALSE(PhotosStateANadirGimbal({}));
}

TEST(ExifGps, APhotoWithoutAUsablePositionGivesNoneAndSaysWhy) {
  testing::TempDir dir;
  std::string why;
  EXPECT_FALSE(ReadExifGps(Photo(dir / "none.jpg", {{"Exif.Image.Make", "DJI"}}), &why));
  EXPECT_NE(why.find("no GPS position"), std::string::npos) << why;
  auto off_earth = ZurichTags();
  off_earth[1].second = "95/1 0/1 0/1";
  EXPECT_FALSE(ReadExifGps(Photo(dir / "far.jpg", off_earth), &why));
  EXPECT_NE(why.find("GPS tags"), std::string::npos) << why;
  auto zero_denominator = ZurichTags();
  zero_denominator[1].second = "47/0 22/1 0/1";
  EXPECT_FALSE(ReadExifGps(Photo(dir / "zero.jpg", zero_denominator), &why));
  auto no_lock = ZurichTags();
  no_lock[1].second = "0/1 0/1 0/1";
  no_lock[3].second = "0/1 0/1 0/1";
  EXPECT_FALSE(ReadExifGps(Photo(dir / "nolock.jpg", no_lock), &why));
  EXPECT_NE(why.find("no lock"), std::string::npos) << why;
  // Not an image at all, and a JPEG cut short.
  { std::ofstream(dir / "text.jpg") << "not a JPEG"; }
  EXPECT_FALSE(ReadExifGps(dir / "text.jpg", &why));
  const std::string whole = Photo(dir / "whole.jpg", ZurichTags());
  std::filesystem::resize_file(whole, 200);
  EXPECT_FALSE(ReadExifGps(whole, &why));
  EXPECT_FALSE(ReadExifGps(dir / "missing.jpg", &why));
}

TEST(ExifGps, AFoldersTrackHasEachPhotosFixAtItsTime) {
  testing::TempDir dir;
  std::vector<ImageEntry> images;
  for (int i = 0; i < 5; ++i) {
    auto tags = ZurichTags();
    tags[1].second = "47/1 22/1 " + std::to_string(632 + 100 * i) + "/100";  // a second of arc further north each
    const std::string name = dir / ("img" + std::to_string(i) + ".jpg");
    images.push_back({int64_t{2'000'000'000} * i, i == 2 ? Photo(name, {}) : Photo(name, tags)});
  }
  const GnssTrack track = ExifGnssTrack(images);
  ASSERT_EQ(track.fixes.size(), 4u) << track.source;
  EXPECT_EQ(track.fixes[2].t_ns, 6'000'000'000) << "photo 3's time: photo 2 has no position";
  EXPECT_GT(track.fixes[3].position.latitude_deg, track.fixes[2].position.latitude_deg);
  EXPECT_NE(track.source.find("1 without a fix"), std::string::npos) << track.source;
  EXPECT_TRUE(ExifGnssTrack({images[2]}).fixes.empty());
}

}  // namespace
}  // namespace stitch
