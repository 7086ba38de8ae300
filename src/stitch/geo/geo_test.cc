// The geo layer with known answers: the local ENU frame against the ellipsoid's own figures,
// gnss.csv read back and refused when malformed, and a map placed on Earth from noisy fixes
// that jump.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "stitch/geo/dji_srt.h"
#include "stitch/geo/geo_outputs.h"
#include "stitch/geo/geo_registration.h"
#include "stitch/geo/geodetic.h"
#include "stitch/geo/geoid.h"
#include "stitch/geo/gnss_fix.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

// On the equator a thousandth of a degree of longitude is a / 1000 x pi / 180 m of arc (WGS84's
// a = 6378137 m); the tangent plane falls away from the ellipsoid by d^2 / 2a below it.
TEST(LocalTangentPlane, PutsThePlaceEastOfTheOriginAlongXAtTheEllipsoidsDistance) {
  const LocalTangentPlane plane({0.0, 10.0, 0.0});
  EXPECT_NEAR(plane.ToEnu({0.0, 10.0, 0.0}).norm(), 0.0, 1e-9);
  const Eigen::Vector3d east = plane.ToEnu({0.0, 10.001, 0.0});
  EXPECT_NEAR(east.x(), 6378137.0 * M_PI / 180.0 * 0.001, 1e-3);
  EXPECT_NEAR(east.y(), 0.0, 1e-6);
  EXPECT_NEAR(east.z(), -east.x() * east.x() / (2 * 6378137.0), 1e-4);
  // North is y, up is z.
  EXPECT_GT(plane.ToEnu({0.001, 10.0, 0.0}).y(), 110.0);
  EXPECT_NEAR(plane.ToEnu({0.0, 10.0, 35.0}).z(), 35.0, 1e-6);
}

TEST(LocalTangentPlane, BringsAPlaceBackToItsCoordinates) {
  const LocalTangentPlane plane({48.0, 11.0, 600.0});
  const Eigen::Vector3d enu(1234.5, -876.25, 70.0);
  const GeodeticPoint place = plane.ToGeodetic(enu);
  EXPECT_NEAR((plane.ToEnu(place) - enu).norm(), 0.0, 1e-6);
  EXPECT_GT(place.latitude_deg, 47.99);
  EXPECT_LT(place.latitude_deg, 48.0);
}

TEST(LocalTangentPlane, RefusesAnOriginThatIsNoPlaceOnEarth) {
  EXPECT_THROW(LocalTangentPlane({91.0, 0.0, 0.0}), Error);
  EXPECT_THROW(LocalTangentPlane({0.0, 181.0, 0.0}), Error);
  EXPECT_THROW(LocalTangentPlane({0.0, 0.0, NAN}), Error);
  EXPECT_THROW(LocalTangentPlane({0.0, 0.0, 1e6}), Error);
}

GnssFix Fix(int64_t t_ns, double lat, double lon, double h) {
  GnssFix f;
  f.t_ns = t_ns;
  f.position = {lat, lon, h};
  f.horizontal_accuracy_m = 1.5;
  f.vertical_accuracy_m = 2.5;
  return f;
}

TEST(GnssCsv, ReadsBackWhatItWrote) {
  testing::TempDir dir;
  GnssTrack track;
  track.source = "test receiver";
  track.ground_truth_enu_origin = GeodeticPoint{48.1, 11.2, 601.5};
  track.fixes = {Fix(1'000'000'000, 48.100001, 11.200002, 650.25), Fix(1'200'000'000, 48.100003, 11.200004, 651.0)};
  track.fixes[1].type = GnssFixType::kRtkFixed;
  WriteGnssCsv((dir / "gnss.csv"), track);
  const GnssTrack back = ReadGnssCsv((dir / "gnss.csv"));
  EXPECT_EQ(back.source, "test receiver");
  ASSERT_TRUE(back.ground_truth_enu_origin);
  EXPECT_DOUBLE_EQ(back.ground_truth_enu_origin->latitude_deg, 48.1);
  ASSERT_EQ(back.fixes.size(), 2u);
  EXPECT_EQ(back.fixes[1].t_ns, 1'200'000'000);
  EXPECT_NEAR(back.fixes[0].position.longitude_deg, 11.200002, 1e-12);
  EXPECT_DOUBLE_EQ(back.fixes[0].position.height_m, 650.25);
  EXPECT_DOUBLE_EQ(back.fixes[0].vertical_accuracy_m, 2.5);
  EXPECT_EQ(back.fixes[1].type, GnssFixType::kRtkFixed);
  // Written again, the same bytes.
  WriteGnssCsv((dir / "again.csv"), back);
  std::ifstream a(dir / "gnss.csv"), b(dir / "again.csv");
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(a), {}), std::string(std::istreambuf_iterator<char>(b), {}));
}

// Every malformed file is refused naming the file and line, with what was wrong.
// A DJI SRT of the newer layout (markup, CRLF lines, a byte-order mark, `longtitude` spelt as
// some firmware does), a block without a lock, and frames closer than the 10 Hz kept.
TEST(DjiSrt, ReadsTheAircraftsPositionPerSubtitleOnTheVideosClock) {
  testing::TempDir dir;
  {
    std::ofstream out(dir / "DJI_0001.SRT", std::ios::binary);
    out << "\xEF\xBB\xBF"
           "1\r\n00:00:00,000 --> 00:00:00,033\r\n<font size=\"28\">FrameCnt: 1, DiffTime: 33ms\r\n"
           "2023-04-08 16:36:41.395\r\n[iso : 100] [latitude: 0.000000] [longitude: 0.000000] [rel_alt: 0.000 "
           "abs_alt: 0.000] </font>\r\n\r\n"
           "2\r\n00:00:00,033 --> 00:00:00,066\r\n<font size=\"28\">FrameCnt: 2\r\n[latitude: 47.368423] "
           "[longtitude : 8.539054] [rel_alt: 1.200 abs_alt: 459.873] </font>\r\n\r\n"
           "3\r\n00:00:00,066 --> 00:00:00,100\r\n[latitude: 47.368424] [longitude: 8.539055] [rel_alt: 1.3 "
           "abs_alt: 459.9]\r\n\r\n"
           "4\r\n00:00:01,134 --> 00:00:01,167\r\n[latitude: 47.368500] [longitude: 8.539100] [altitude: 461.5]\r\n";
  }
  const GnssTrack track = ReadDjiSrt(dir / "DJI_0001.SRT");
  EXPECT_EQ(track.source, "DJI SRT DJI_0001.SRT");
  ASSERT_EQ(track.fixes.size(), 2u) << "no lock left out, the third within 0.1 s of the second";
  EXPECT_EQ(track.fixes[0].t_ns, 33'000'000);
  EXPECT_DOUBLE_EQ(track.fixes[0].position.latitude_deg, 47.368423);
  EXPECT_DOUBLE_EQ(track.fixes[0].position.longitude_deg, 8.539054);
  EXPECT_DOUBLE_EQ(track.fixes[0].position.height_m, 459.873);
  EXPECT_TRUE(track.fixes[0].height_above_msl);  // abs_alt
  EXPECT_DOUBLE_EQ(track.fixes[0].horizontal_accuracy_m, kDjiSrtHorizontalAccuracyM);
  EXPECT_EQ(track.fixes[1].t_ns, 1'134'000'000);
  EXPECT_DOUBLE_EQ(track.fixes[1].position.height_m, 461.5);
}

// The older layout: GPS(longitude,latitude,height) with the barometer's height.
TEST(DjiSrt, ReadsTheOlderGpsLayout) {
  testing::TempDir dir;
  {
    std::ofstream out(dir / "old.srt");
    out << "1\n00:00:00,000 --> 00:00:01,000\nHOME(8.5390,47.3684) 2017.08.05 14:11:51\n"
           "GPS(8.5391,47.3685,19) BAROMETER:61.5\nISO:100 Shutter:60 EV: Fnum:F2.8\n\n"
           "2\n00:00:01,000 --> 00:00:02,000\nGPS(8.5392,47.3686,19)\n";
  }
  const GnssTrack track = ReadDjiSrt(dir / "old.srt");
  ASSERT_EQ(track.fixes.size(), 2u);
  EXPECT_DOUBLE_EQ(track.fixes[0].position.longitude_deg, 8.5391);
  EXPECT_DOUBLE_EQ(track.fixes[0].position.latitude_deg, 47.3685);
  EXPECT_DOUBLE_EQ(track.fixes[0].position.height_m, 61.5);
  EXPECT_FALSE(track.fixes[0].height_above_msl);  // the barometer's, above the take-off point
  EXPECT_DOUBLE_EQ(track.fixes[1].position.height_m, 19.0);
  EXPECT_EQ(track.fixes[1].t_ns, 1'000'000'000);
}

TEST(DjiSrt, RefusesWhatIsNoTrackNamingTheLine) {
  testing::TempDir dir;
  const std::string block = "00:00:00,000 --> 00:00:00,033\n";
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"hello\n", ":1: not a DJI SRT"},
      {"1\nno time here\n", ":2: a subtitle without its time line"},
      {"1\n" + block + "[latitude: 47.x] [longitude: 8.5]\n", ":2: the latitude is not a number"},
      {"1\n" + block + "[latitude: 95.0] [longitude: 8.5]\n", ":2: latitude 95"},
      {"1\n" + block + "[latitude: 47.0]\n", "without a longitude"},
      {"1\n00:00:02,000 --> 00:00:02,033\n[latitude: 47] [longitude: 8]\n\n2\n" + block +
           "[latitude: 47] [longitude: 8]\n",
       ":6: its time goes back"},
      {"1\n" + block + "[iso : 100]\n", "no position in any of its 1 subtitles"},
      {"", "no position"},
  };
  for (const auto& [text, expected] : cases) {
    {
      std::ofstream out(dir / "bad.SRT", std::ios::trunc);
      out << text;
    }
    try {
      ReadDjiSrt(dir / "bad.SRT");
      ADD_FAILURE() << "accepted: " << text;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what() << " for: " << text;
    }
  }
  EXPECT_THROW(ReadDjiSrt(dir / "missing.SRT"), Error);
}

TEST(GnssCsv, RefusesWhatIsNoFixNamingTheLine) {
  testing::TempDir dir;
  const std::string header = "t_ns,latitude_deg,longitude_deg,height_m,horizontal_accuracy_m,vertical_accuracy_m,fix\n";
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"1,48,11,600,1,1,3d\n", "header"},
      {header + "1,48,11,600,1,1\n", "6 fields"},
      {header + "1,48,11,600,1,1,3d,7\n", "8 fields"},
      {header + "1,48.x,11,600,1,1,3d\n", "field 2 is not a number"},
      {header + "1,nan,11,600,1,1,3d\n", "field 2 is not a number"},
      {header + "1,91,11,600,1,1,3d\n", "latitude 91"},
      {header + "1,48,-181,600,1,1,3d\n", "longitude -181"},
      {header + "1,48,11,600,0,1,3d\n", "accuracy"},
      {header + "1,48,11,600,1,-2,3d\n", "accuracy"},
      {header + "-5,48,11,600,1,1,3d\n", "t_ns is not a time"},
      {header + "99999999999999999999,48,11,600,1,1,3d\n", "t_ns is not a time"},
      {header + "9999999999999999999,48,11,600,1,1,3d\n", "t_ns is not a time"},
      {header + "1,48,11,600,1,1,4d\n", "fix \"4d\""},
      {header + "2,48,11,600,1,1,3d\n1,48,11,600,1,1,3d\n", "do not increase"},
      {"# ground_truth_enu_origin: 48 11\n" + header, "ground_truth_enu_origin needs"},
      {"# ground_truth_enu_origin: 95 11 0\n" + header, "latitude 95"},
      {"", "no header line"},
  };
  for (const auto& [text, expected] : cases) {
    {
      std::ofstream out(dir / "bad.csv", std::ios::trunc);
      out << text;
    }
    try {
      ReadGnssCsv((dir / "bad.csv"));
      ADD_FAILURE() << "accepted: " << text;
    } catch (const Error& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find((dir / "bad.csv")), std::string::npos) << what;
      EXPECT_NE(what.find(expected), std::string::npos) << "expected \"" << expected << "\" in: " << what;
    }
  }
  // A fix of type none may say anything of its position; it is kept, and not used.
  {
    std::ofstream out(dir / "none.csv", std::ios::trunc);
    out << header << "1,0,0,0,1,1,none\n";
  }
  const GnssTrack none = ReadGnssCsv((dir / "none.csv"));
  ASSERT_EQ(none.fixes.size(), 1u);
  EXPECT_TRUE(ToEnu(none.fixes, LocalTangentPlane({48, 11, 600})).empty());
}

// A survey's camera path in ENU (a lawnmower of 4 strips, 240 m long, 40 m apart, at 70 m, nadir
// camera heading along the strip), sampled at 20 Hz.
std::vector<StampedPose> SurveyInEnu() {
  std::vector<StampedPose> poses;
  const int per_strip = 240;
  for (int strip = 0; strip < 4; ++strip) {
    for (int i = 0; i < per_strip; ++i) {
      const double along = strip % 2 == 0 ? i : per_strip - 1 - i;
      StampedPose p;
      p.t_ns = static_cast<int64_t>(strip * per_strip + i) * 50'000'000LL;
      // Camera looking down: z (optical axis) = -up, x = east, y = -north.
      Eigen::Matrix3d world_from_cam;
      world_from_cam.col(0) = Eigen::Vector3d(1, 0, 0);
      world_from_cam.col(1) = Eigen::Vector3d(0, -1, 0);
      world_from_cam.col(2) = Eigen::Vector3d(0, 0, -1);
      p.world_from_cam = Rigid3d(Eigen::Quaterniond(world_from_cam), Eigen::Vector3d(along, 40.0 * strip, 70.0));
      poses.push_back(p);
    }
  }
  return poses;
}

// The same path as a map would hold it: in a frame of its own, at a scale of its own.
Trajectory InMapFrame(const std::vector<StampedPose>& truth, const Sim3d& map_from_enu) {
  Trajectory map;
  for (const StampedPose& p : truth) map.Add({p.t_ns, TransformPose(map_from_enu, p.world_from_cam)});
  return map;
}

const Sim3d kMapFromEnu(0.02, Eigen::Quaterniond(Eigen::AngleAxisd(2.0, Eigen::Vector3d(0.3, -0.5, 0.8).normalized())),
                        Eigen::Vector3d(3.0, -1.0, 0.5));

// Fixes at 5 Hz of the antenna `antenna_in_cam` (metres) with 2 m horizontal and 3 m vertical noise.
std::vector<EnuFix> NoisyFixes(const std::vector<StampedPose>& truth, const Eigen::Vector3d& antenna_in_cam,
                               double horizontal_sigma, double vertical_sigma) {
  std::vector<EnuFix> fixes;
  Rng rng(7);
  for (size_t i = 0; i < truth.size(); i += 4) {
    const Rigid3d& pose = truth[i].world_from_cam;
    EnuFix f;
    f.t_ns = truth[i].t_ns;
    f.enu = pose.translation + pose.rotation * antenna_in_cam +
            Eigen::Vector3d(rng.Normal(0, horizontal_sigma), rng.Normal(0, horizontal_sigma),
                            rng.Normal(0, vertical_sigma));
    f.horizontal_sigma_m = std::max(horizontal_sigma, 0.01);
    f.vertical_sigma_m = std::max(vertical_sigma, 0.01);
    fixes.push_back(f);
  }
  return fixes;
}

double PlacedRms(const GeoPlacement& placement, const Trajectory& map, const std::vector<StampedPose>& truth) {
  double sum = 0;
  for (size_t i = 0; i < truth.size(); ++i) {
    sum += (placement.enu_from_map * map.poses()[i].world_from_cam.translation - truth[i].world_from_cam.translation)
               .squaredNorm();
  }
  return std::sqrt(sum / truth.size());
}

// 192 fixes of 2 m noise, a fifth of them thrown 100 m north by multipath: the map is placed
// within half a metre of the truth and the jumps are reported as outliers.
TEST(PlaceByGnss, PlacesAMapWithinItsFixesNoiseAndIgnoresJumps) {
  const std::vector<StampedPose> truth = SurveyInEnu();
  const Trajectory map = InMapFrame(truth, kMapFromEnu);
  std::vector<EnuFix> fixes = NoisyFixes(truth, Eigen::Vector3d::Zero(), 2.0, 3.0);
  int jumped = 0;
  for (size_t i = 50; i < 50 + fixes.size() / 5; ++i, ++jumped) fixes[i].enu.y() += 100.0;
  const GeoPlacement placement = PlaceByGnss(map, fixes, GeoReferenceOptions());
  ASSERT_TRUE(placement.placed) << placement.why_not;
  EXPECT_EQ(placement.method, "gnss");
  EXPECT_EQ(placement.fixes_matched, static_cast<int>(fixes.size()));
  EXPECT_GE(placement.inliers, static_cast<int>(fixes.size()) - jumped - 3);
  EXPECT_LE(placement.inliers, static_cast<int>(fixes.size()) - jumped);
  EXPECT_LT(PlacedRms(placement, map, truth), 0.5);
  EXPECT_NEAR(placement.enu_from_map.scale, 1.0 / kMapFromEnu.scale, 0.005 / kMapFromEnu.scale);
  EXPECT_NEAR(placement.horizontal_rms_m, 2.0 * std::sqrt(2.0), 0.6);
  // The jump is one span of outliers, from its first fix to its last (a right fix now and then
  // falls outside the bound too: 0.3% of them).
  const std::pair<int64_t, int64_t> jump{fixes[50].t_ns, fixes[50 + jumped - 1].t_ns};
  EXPECT_NE(std::find(placement.outlier_spans.begin(), placement.outlier_spans.end(), jump),
            placement.outlier_spans.end());
  EXPECT_LE(placement.outlier_spans.size(), 3u);
}

// Fixes whose heights lean by a degree across the strips (what a few metres of vertical noise does
// to a survey's tilt) tilt the map by as much; a gimballed camera's stated up axis levels it.
TEST(PlaceByGnss, LevelsAMapByItsCamerasWhereTheirMountIsStated) {
  const std::vector<StampedPose> truth = SurveyInEnu();
  const Trajectory map = InMapFrame(truth, kMapFromEnu);
  std::vector<EnuFix> fixes = NoisyFixes(truth, Eigen::Vector3d::Zero(), 0.5, 0.5);
  double mean_y = 0;
  for (const EnuFix& f : fixes) mean_y += f.enu.y() / static_cast<double>(fixes.size());
  for (EnuFix& f : fixes) f.enu.z() += std::tan(1.0 * M_PI / 180.0) * (f.enu.y() - mean_y);
  const auto tilt_deg = [&](const GeoPlacement& placement) {
    // The placed cameras' optical axes against the truth's (straight down).
    const Eigen::Vector3d axis =
        placement.enu_from_map.rotation * (map.poses()[0].world_from_cam.rotation * Eigen::Vector3d::UnitZ());
    return std::acos(std::clamp(-axis.z(), -1.0, 1.0)) * 180.0 / M_PI;
  };
  GeoReferenceOptions options;
  const GeoPlacement tilted = PlaceByGnss(map, fixes, options);
  ASSERT_TRUE(tilted.placed) << tilted.why_not;
  EXPECT_NEAR(tilt_deg(tilted), 1.0, 0.15);
  options.level_by_camera = "true";
  EXPECT_NEAR(tilt_deg(PlaceByGnss(map, fixes, options)), 1.0, 0.15);  // auto: no mount stated
  options.camera_up_axis = "-z";
  options.level_by_camera = "auto";  // stitch run resolves it from the source; alone, nothing stated it
  EXPECT_NEAR(tilt_deg(PlaceByGnss(map, fixes, options)), 1.0, 0.15);
  options.level_by_camera = "true";
  const GeoPlacement level = PlaceByGnss(map, fixes, options);
  ASSERT_TRUE(level.placed) << level.why_not;
  EXPECT_EQ(level.method, "gnss+level");
  EXPECT_LT(tilt_deg(level), 0.01);
  // Its cameras stay where the fixes put them, within their noise: closer to the truth than tilted.
  EXPECT_LT(PlacedRms(level, map, truth), 0.3);
  EXPECT_LT(PlacedRms(level, map, truth), PlacedRms(tilted, map, truth));
}

// From half the flight on the receiver puts every fix 20 m east (a datum switch, a spoofer): the
// map stays where the fixes that came first put it, and the other group is reported with when it
// began and how far off it would put the map.
TEST(PlaceByGnss, HoldsTheMapWhereTheFirstFixesPutItAndReportsAGroupThatJumped) {
  const std::vector<StampedPose> truth = SurveyInEnu();
  const Trajectory map = InMapFrame(truth, kMapFromEnu);
  std::vector<EnuFix> fixes = NoisyFixes(truth, Eigen::Vector3d::Zero(), 2.0, 3.0);
  const size_t from = fixes.size() / 2;
  for (size_t i = from; i < fixes.size(); ++i) fixes[i].enu.x() += 20.0;
  const GeoPlacement placement = PlaceByGnss(map, fixes, GeoReferenceOptions());
  ASSERT_TRUE(placement.placed) << placement.why_not;
  EXPECT_LT(PlacedRms(placement, map, truth), 2.0);  // by the first two strips: the other two extrapolated
  ASSERT_TRUE(placement.disagreement);
  EXPECT_GE(placement.disagreement->fixes, static_cast<int>(fixes.size() - from) - 3);
  EXPECT_EQ(placement.disagreement->first_ns, fixes[from].t_ns);
  EXPECT_NEAR(placement.disagreement->apart_m, 20.0, 1.0);
  // Without the offset, no group of outliers.
  EXPECT_FALSE(PlaceByGnss(map, NoisyFixes(truth, Eigen::Vector3d::Zero(), 2.0, 3.0), {}).disagreement);
}

// The antenna a metre behind the camera: with its offset set, the map lands on the camera
// positions; without, a metre off.
TEST(PlaceByGnss, TakesTheAntennasOffsetFromTheCamera) {
  const std::vector<StampedPose> truth = SurveyInEnu();
  const Trajectory map = InMapFrame(truth, kMapFromEnu);
  const Eigen::Vector3d antenna(0.0, -1.0, 0.2);  // camera y is south here: the antenna is 1 m north
  const std::vector<EnuFix> fixes = NoisyFixes(truth, antenna, 0.0, 0.0);
  GeoReferenceOptions options;
  const GeoPlacement without = PlaceByGnss(map, fixes, options);
  options.antenna_y_m = antenna.y();
  options.antenna_z_m = antenna.z();
  const GeoPlacement with = PlaceByGnss(map, fixes, options);
  ASSERT_TRUE(with.placed) << with.why_not;
  EXPECT_LT(PlacedRms(with, map, truth), 0.01);
  EXPECT_GT(PlacedRms(without, map, truth), 0.9);
}

TEST(PlaceByGnss, SaysWhyItCannotPlaceAMap) {
  const std::vector<StampedPose> truth = SurveyInEnu();
  const Trajectory map = InMapFrame(truth, kMapFromEnu);
  const std::vector<EnuFix> fixes = NoisyFixes(truth, Eigen::Vector3d::Zero(), 2.0, 3.0);
  // Too few fixes within its frames.
  const GeoPlacement few = PlaceByGnss(map, std::vector<EnuFix>(fixes.begin(), fixes.begin() + 5), {});
  EXPECT_FALSE(few.placed);
  EXPECT_NE(few.why_not.find("5 fixes within its frames (needs 10)"), std::string::npos) << few.why_not;
  // One strip: a line, about which the fixes do not say the rotation; without the cameras' up, not placed.
  const std::vector<StampedPose> strip(truth.begin(), truth.begin() + 240);
  GeoReferenceOptions no_up;
  no_up.camera_up_axis = "none";
  const GeoPlacement line = PlaceByGnss(InMapFrame(strip, kMapFromEnu), fixes, no_up);
  EXPECT_FALSE(line.placed);
  EXPECT_NE(line.why_not.find("along a line"), std::string::npos) << line.why_not;
  // Cameras that look every way: no up to take.
  std::vector<StampedPose> tumbling = strip;
  for (size_t i = 0; i < tumbling.size(); ++i) {
    tumbling[i].world_from_cam.rotation =
        Eigen::Quaterniond(Eigen::AngleAxisd(0.7 * i, Eigen::Vector3d(1, 1, 0).normalized()));
  }
  const GeoPlacement lost = PlaceByGnss(InMapFrame(tumbling, kMapFromEnu), fixes, {});
  EXPECT_FALSE(lost.placed);
  EXPECT_NE(lost.why_not.find("do not say which way is up"), std::string::npos) << lost.why_not;
  // Fixes that agree on nothing.
  std::vector<EnuFix> scattered = fixes;
  Rng rng(3);
  for (EnuFix& f : scattered) f.enu += Eigen::Vector3d(rng.Uniform(-500, 500), rng.Uniform(-500, 500), 0);
  const GeoPlacement chaos = PlaceByGnss(map, scattered, {});
  EXPECT_FALSE(chaos.placed);
  EXPECT_NE(chaos.why_not.find("agree"), std::string::npos) << chaos.why_not;
}

// A single strip (a submap between two gusts): its fixes fix the line, the nadir camera's up the
// rotation about it; placed within its fixes' noise, the rotation within a few degrees.
TEST(PlaceByGnss, PlacesAStraightStripByItsCamerasUp) {
  const std::vector<StampedPose> survey = SurveyInEnu();
  const std::vector<StampedPose> strip(survey.begin() + 240, survey.begin() + 480);
  const Trajectory map = InMapFrame(strip, kMapFromEnu);
  const GeoPlacement placement = PlaceByGnss(map, NoisyFixes(strip, Eigen::Vector3d::Zero(), 2.0, 3.0), {});
  ASSERT_TRUE(placement.placed) << placement.why_not;
  EXPECT_EQ(placement.method, "gnss+camera-up");
  EXPECT_LT(PlacedRms(placement, map, strip), 1.0);
  const Eigen::Quaterniond error = placement.enu_from_map.rotation * kMapFromEnu.rotation;
  EXPECT_LT(Eigen::AngleAxisd(error).angle(), 3.0 * M_PI / 180.0);
}

// A car's forward camera (z along the heading, y down) 1.5 m up, at 1 m a frame (10 Hz): 120 m
// east, a quarter turn of 12 m radius to the north, then 160 m north.
std::vector<StampedPose> CarInEnu() {
  std::vector<StampedPose> poses;
  const auto add = [&poses](const Eigen::Vector3d& at, double heading) {  // heading from east, counterclockwise
    const Eigen::Vector3d forward(std::cos(heading), std::sin(heading), 0), down(0, 0, -1);
    Eigen::Matrix3d world_from_cam;
    world_from_cam.col(0) = down.cross(forward);  // right: x = y cross z
    world_from_cam.col(1) = down;
    world_from_cam.col(2) = forward;
    StampedPose p;
    p.t_ns = static_cast<int64_t>(poses.size()) * 100'000'000LL;
    p.world_from_cam = Rigid3d(Eigen::Quaterniond(world_from_cam), at);
    poses.push_back(p);
  };
  for (int i = 0; i < 120; ++i) add(Eigen::Vector3d(i, 0, 1.5), 0.0);
  for (int i = 0; i < 19; ++i) {
    const double a = i * (M_PI / 2) / 19;
    add(Eigen::Vector3d(120 + 12 * std::sin(a), 12 * (1 - std::cos(a)), 1.5), a);
  }
  for (int i = 0; i < 160; ++i) add(Eigen::Vector3d(132, 12 + i, 1.5), M_PI / 2);
  return poses;
}

// The car lost track on the street north after its turn and its camera began a new map there: that map's fixes lie
// along a line, and its camera's -z axis (the default of a nadir camera) points along it. The first map, which took the
// turn, is placed by its fixes alone and shows which way is up in the camera; the second takes that up and is placed
// within its fixes' noise, the rotation within a few degrees. Without the learned up (camera_up_axis -z) it is not.
TEST(PlaceMapsByGnss, AStraightStreetTakesTheUpItsTurnShowed) {
  const std::vector<StampedPose> car = CarInEnu();
  const std::vector<StampedPose> turn(car.begin(), car.begin() + 200), street(car.begin() + 210, car.end());
  const Sim3d street_from_enu(0.05,
                              Eigen::Quaterniond(Eigen::AngleAxisd(-1.1, Eigen::Vector3d(0.2, 0.9, -0.4).normalized())),
                              Eigen::Vector3d(-2.0, 0.3, 1.0));
  const Trajectory turn_map = InMapFrame(turn, kMapFromEnu), street_map = InMapFrame(street, street_from_enu);
  const std::vector<EnuFix> fixes = NoisyFixes(car, Eigen::Vector3d::Zero(), 2.0, 3.0);
  const std::vector<GeoPlacement> placed =
      PlaceMapsByGnss({{&turn_map, &fixes}, {&street_map, &fixes}}, GeoReferenceOptions());
  ASSERT_EQ(placed.size(), 2u);
  ASSERT_TRUE(placed[0].placed) << placed[0].why_not;
  EXPECT_EQ(placed[0].method, "gnss");
  ASSERT_TRUE(placed[0].up_in_camera);
  EXPECT_LT(placed[0].up_in_camera->cross(-Eigen::Vector3d::UnitY()).norm(), 0.05)
      << placed[0].up_in_camera->transpose();
  ASSERT_TRUE(placed[1].placed) << placed[1].why_not;
  EXPECT_EQ(placed[1].method, "gnss+learned-camera-up");
  EXPECT_LT(PlacedRms(placed[1], street_map, street), 1.5);
  const Eigen::Quaterniond error = placed[1].enu_from_map.rotation * street_from_enu.rotation;
  EXPECT_LT(Eigen::AngleAxisd(error).angle(), 3.0 * M_PI / 180.0);

  GeoReferenceOptions nadir;
  nadir.camera_up_axis = "-z";
  const std::vector<GeoPlacement> unlearned = PlaceMapsByGnss({{&turn_map, &fixes}, {&street_map, &fixes}}, nadir);
  EXPECT_TRUE(unlearned[0].placed);
  EXPECT_FALSE(unlearned[1].placed);
  EXPECT_NE(unlearned[1].why_not.find("do not say which way is up"), std::string::npos) << unlearned[1].why_not;
}

TEST(GeoOutputs, WriteGeoJsonCoordinatesAsLongitudeLatitudeHeight) {
  testing::TempDir dir;
  GeoTrack track;
  track.name = "map-0";
  track.submaps = "0:1,0:2";
  track.placed_by = "gnss";
  track.points = {{1, 0, {48.0, 11.0, 650.0}}, {2, 1, {48.0001, 11.0002, 651.0}}};
  GeoTrack lone = track;
  lone.name = "submap-0-3 <&>";
  lone.points.resize(1);
  WriteGeoJson((dir / "t.geojson"), {track, lone});
  std::ifstream in(dir / "t.geojson");
  const nlohmann::json json = nlohmann::json::parse(in);
  ASSERT_EQ(json["features"].size(), 2u);
  const auto& line = json["features"][0]["geometry"];
  EXPECT_EQ(line["type"], "LineString");
  EXPECT_DOUBLE_EQ(line["coordinates"][1][0].get<double>(), 11.0002);
  EXPECT_DOUBLE_EQ(line["coordinates"][1][1].get<double>(), 48.0001);
  EXPECT_EQ(json["features"][1]["geometry"]["type"], "Point");
  WriteKml((dir / "t.kml"), {track, lone});
  std::ifstream kml(dir / "t.kml");
  const std::string text(std::istreambuf_iterator<char>(kml), {});
  EXPECT_NE(text.find("11.000200000,48.000100000,651.000"), std::string::npos);
  EXPECT_NE(text.find("submap-0-3 &lt;&amp;&gt;"), std::string::npos);
  WriteGeoTrajectoryCsv((dir / "t.csv"), {track});
  std::ifstream csv(dir / "t.csv");
  std::string header, first;
  std::getline(csv, header);
  std::getline(csv, first);
  EXPECT_EQ(header, "map,frame,t_ns,latitude_deg,longitude_deg,height_m");
  EXPECT_EQ(first, "map-0,0,1,48.000000000,11.000000000,650.000");
}

// trajectory_wgs84.csv read back: each map's positions as written (1e-9 degrees, millimetres),
// and anything else refused naming the file and line.
TEST(GeoOutputs, ReadsBackTheTrajectoryCsvAndRefusesWhatIsNotOne) {
  testing::TempDir dir;
  GeoTrack a, b;
  a.name = "map-0";
  b.name = "submap-0-3";
  for (int i = 0; i < 3; ++i) {
    a.points.push_back({1000 + i, i, {48.0 + 1e-5 * i, 11.0 - 2e-5 * i, 650.0 + 0.25 * i}});
    b.points.push_back({5000 + i, 10 + i, {-33.5, 151.25, -10.0 * i}});
  }
  WriteGeoTrajectoryCsv((dir / "t.csv"), {a, b});
  EXPECT_TRUE(IsGeoTrajectoryCsv((dir / "t.csv")));
  const std::vector<GeoTrack> read = ReadGeoTrajectoryCsv((dir / "t.csv"));
  ASSERT_EQ(read.size(), 2u);
  for (size_t t = 0; t < 2; ++t) {
    const GeoTrack& written = t == 0 ? a : b;
    EXPECT_EQ(read[t].name, written.name);
    ASSERT_EQ(read[t].points.size(), written.points.size());
    for (size_t i = 0; i < written.points.size(); ++i) {
      EXPECT_EQ(read[t].points[i].t_ns, written.points[i].t_ns);
      EXPECT_EQ(read[t].points[i].frame_index, written.points[i].frame_index);
      EXPECT_NEAR(read[t].points[i].position.latitude_deg, written.points[i].position.latitude_deg, 1e-9);
      EXPECT_NEAR(read[t].points[i].position.longitude_deg, written.points[i].position.longitude_deg, 1e-9);
      EXPECT_NEAR(read[t].points[i].position.height_m, written.points[i].position.height_m, 1e-3);
    }
  }
  const std::string header = "map,frame,t_ns,latitude_deg,longitude_deg,height_m\n";
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"t_ns,latitude_deg,longitude_deg,height_m,horizontal_accuracy_m,vertical_accuracy_m,fix\n", "header"},
      {"", "empty"},
      {header + "map-0,0,1,48,11\n", "5 fields"},
      {header + "map-0,0.5,1,48,11,600\n", "frame is not a frame number"},
      {header + "map-0,0,-1,48,11,600\n", "t_ns is not a time"},
      {header + "map-0,0,1,48,east,600\n", "field 5 is not a number"},
      {header + "map-0,0,1,-91,11,600\n", "latitude -91"},
      {header + "map-0,0,1,48,11,1e9\n", "height"},
  };
  for (const auto& [text, expected] : cases) {
    {
      std::ofstream out(dir / "bad.csv", std::ios::trunc);
      out << text;
    }
    try {
      ReadGeoTrajectoryCsv((dir / "bad.csv"));
      ADD_FAILURE() << "accepted: " << text;
    } catch (const Error& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find((dir / "bad.csv")), std::string::npos) << what;
      EXPECT_NE(what.find(expected), std::string::npos) << "expected \"" << expected << "\" in: " << what;
    }
  }
  std::ofstream(dir / "poses.tum") << "1.0 0 0 0 0 0 0 1\n";
  EXPECT_FALSE(IsGeoTrajectoryCsv((dir / "poses.tum")));
  EXPECT_FALSE(IsGeoTrajectoryCsv((dir / "missing.csv")));
}

// What GDAL's ogrinfo (not ours) says of `path`: its summary of every layer; empty when it fails.
std::string OgrInfo(const std::string& path) {
  std::string text;
  FILE* pipe = popen(("ogrinfo -ro -al -so '" + path + "' 2>&1").c_str(), "r");
  if (!pipe) return text;
  char buffer[4096];
  while (size_t n = fread(buffer, 1, sizeof(buffer), pipe)) text.append(buffer, n);
  return pclose(pipe) == 0 ? text : "";
}

// GeoJSON and KML as GIS tools read them: two 3D lines in WGS84 over the places written.
TEST(GeoOutputs, GdalReadsTheGeoJsonAndKmlAsLinesInWgs84) {
  if (std::system("command -v ogrinfo >/dev/null 2>&1") != 0) {
    GTEST_SKIP() << "ogrinfo (Debian's gdal-bin) is not installed";
  }
  testing::TempDir dir;
  GeoTrack a;
  a.name = "map-0";
  a.placed_by = "gnss";
  a.points = {{1, 0, {48.0, 11.0, 650.0}}, {2, 1, {48.001, 11.002, 651.0}}};
  GeoTrack b = a;
  b.name = "submap-0-4";
  b.points = {{3, 2, {47.999, 10.999, 640.0}}, {4, 3, {47.998, 10.998, 641.0}}};
  WriteGeoJson(dir / "t.geojson", {a, b});
  WriteKml(dir / "t.kml", {a, b});
  const std::string geojson = OgrInfo(dir / "t.geojson");
  EXPECT_NE(geojson.find("Geometry: 3D Line String"), std::string::npos) << geojson;
  EXPECT_NE(geojson.find("Feature Count: 2"), std::string::npos) << geojson;
  EXPECT_NE(geojson.find("Extent: (10.998000, 47.998000) - (11.002000, 48.001000)"), std::string::npos) << geojson;
  EXPECT_NE(geojson.find("WGS 84"), std::string::npos) << geojson;
  const std::string kml = OgrInfo(dir / "t.kml");
  EXPECT_NE(kml.find("Feature Count: 2"), std::string::npos) << kml;
  EXPECT_NE(kml.find("Extent: (10.998000, 47.998000) - (11.002000, 48.001000)"), std::string::npos) << kml;
}

// EGM96's geoid heights, through PROJ's grid (Debian's proj-data): where they are published
// (17.16 m at 0 N 0 E; about -29 m at Everest) and where gpsd's own model puts Zurich's (its
// altHAE less altMSL: 47.25 m), to a decimetre or two (the 15' grid is interpolated).
TEST(Geoid, Egm96GivesTheGeoidsHeightWhereItIsKnown) {
  const Geoid geoid = Geoid::Egm96();
  EXPECT_NEAR(geoid.HeightAboveEllipsoid(0.0, 0.0), 17.16, 0.05);
  EXPECT_NEAR(geoid.HeightAboveEllipsoid(27.988, 86.925), -29.0, 0.5);
  EXPECT_NEAR(geoid.HeightAboveEllipsoid(47.368423, 8.539054), 47.25, 0.2);
  EXPECT_THROW(geoid.HeightAboveEllipsoid(91.0, 0.0), Error);
  EXPECT_THROW(geoid.HeightAboveEllipsoid(0.0, std::nan("")), Error);
}

// A track's heights above mean sea level raised to the ellipsoid, once; those above the
// ellipsoid and fixes without a position left as they are.
TEST(Geoid, RaisesHeightsAboveMeanSeaLevelToTheEllipsoid) {
  std::vector<GnssFix> fixes(3);
  for (GnssFix& fix : fixes) fix.position = {47.368423, 8.539054, 459.87};
  fixes[0].height_above_msl = true;
  fixes[2].height_above_msl = true;
  fixes[2].type = GnssFixType::kNone;
  EXPECT_EQ(HeightsAboveEllipsoid(&fixes), "");
  EXPECT_NEAR(fixes[0].position.height_m, 459.87 + 47.25, 0.2);
  EXPECT_FALSE(fixes[0].height_above_msl);
  EXPECT_DOUBLE_EQ(fixes[1].position.height_m, 459.87);
  EXPECT_DOUBLE_EQ(fixes[2].position.height_m, 459.87);
  const double raised = fixes[0].position.height_m;
  EXPECT_EQ(HeightsAboveEllipsoid(&fixes), "");
  EXPECT_DOUBLE_EQ(fixes[0].position.height_m, raised);  // not twice
}

}  // namespace
}  // namespace stitch
