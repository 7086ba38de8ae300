// A finished run placed on Earth: each of its maps by the fixes of its own frames, the absolute
// errors where the truth is in the fixes' ENU frame, and the files a surveyor opens.

#include "stitch/eval/georeference.h"

#include "stitch/geo/las.h"

#include <fstream>

#include <gtest/gtest.h>

#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"
#include "stitch/util/ids.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

const GeodeticPoint kOrigin{48.0, 11.0, 600.0};

// A nadir camera at 70 m in ENU at time index i: the first 600 frames a lawnmower (merged map
// 0, two submaps), then 200 frames along a straight line (a submap on its own).
Rigid3d TrueCamera(int i) {
  Eigen::Matrix3d world_from_cam;
  world_from_cam << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  const int strip = i / 150, along = i % 150;
  const Eigen::Vector3d centre = i < 600 ? Eigen::Vector3d(strip % 2 ? 149 - along : along, 40.0 * strip, 70.0)
                                         : Eigen::Vector3d(i - 600, 200.0, 70.0);
  return Rigid3d(Eigen::Quaterniond(world_from_cam), centre);
}

struct FlownRun {
  std::vector<PoseRecord> poses;
  Trajectory truth;
  GnssTrack gnss;
};

// The largest map's frame in the truth's ENU frame (MakeRun).
const Sim3d kMap0FromEnu(0.05, Eigen::Quaterniond(Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitY())), {1, 2, 3});

// The map's frame: each map of its own, at its own scale.
FlownRun MakeRun() {
  FlownRun run;
  const Sim3d& map0_from_enu = kMap0FromEnu;
  const Sim3d map1_from_enu(0.2, Eigen::Quaterniond(Eigen::AngleAxisd(-1.2, Eigen::Vector3d::UnitX())), {0, 0, 0});
  Rng rng(5);
  const LocalTangentPlane plane(kOrigin);
  run.gnss.ground_truth_enu_origin = kOrigin;
  run.gnss.source = "test";
  for (int i = 0; i < 800; ++i) {
    const int64_t t_ns = 1'000'000'000LL + i * 50'000'000LL;
    const Rigid3d truth = TrueCamera(i);
    run.truth.Add({t_ns, truth});
    PoseRecord p;
    p.frame_index = i;
    p.t_ns = t_ns;
    p.submap_id = MakeSubmapId(0, i < 300 ? 1 : (i < 600 ? 2 : 3)).value;
    p.component = i < 600 ? 0 : 1;
    p.is_keyframe = i % 5 == 0;
    p.world_from_cam = TransformPose(i < 600 ? map0_from_enu : map1_from_enu, truth);
    run.poses.push_back(p);
    if (i % 4 == 0) {
      GnssFix fix;
      fix.t_ns = t_ns;
      fix.position =
          plane.ToGeodetic(truth.translation + Eigen::Vector3d(rng.Normal(0, 2), rng.Normal(0, 2), rng.Normal(0, 3)));
      fix.horizontal_accuracy_m = 2;
      fix.vertical_accuracy_m = 3;
      run.gnss.fixes.push_back(fix);
    }
  }
  return run;
}

TEST(GeoReferenceRun, PlacesEachMapByItsOwnFixesAndMeasuresItAgainstTheTruthUnaligned) {
  const FlownRun run = MakeRun();
  const RunGeoReference geo = GeoReferenceRun(run.poses, 0, run.gnss, run.truth, GeoReferenceOptions());
  EXPECT_EQ(geo.fixes, 200);
  EXPECT_DOUBLE_EQ(geo.origin.latitude_deg, kOrigin.latitude_deg);
  ASSERT_EQ(geo.maps.size(), 2u);
  const MapGeoReference& merged = geo.maps[0];
  EXPECT_EQ(merged.map.name, "map-0");
  ASSERT_TRUE(merged.placement.placed) << merged.placement.why_not;
  EXPECT_EQ(merged.placement.fixes_matched, 150);
  ASSERT_TRUE(merged.absolute);
  EXPECT_EQ(merged.absolute->frames, 600);
  EXPECT_EQ(merged.absolute->keyframes, 120);
  EXPECT_LT(merged.absolute->keyframe_horizontal_rms_m, 1.0);  // the bar for 2 m fixes at 5 Hz
  EXPECT_LT(merged.absolute->vertical_rms_m, 1.0);
  EXPECT_LT(std::abs(merged.absolute->scale_error), 0.01);
  // The straight line: its rotation about itself from the camera's up, as the merged map (placed
  // by its fixes alone) shows it in the camera's frame.
  const MapGeoReference& line = geo.maps[1];
  EXPECT_EQ(line.map.name, "submap-0-3");
  ASSERT_TRUE(line.placement.placed) << line.placement.why_not;
  EXPECT_EQ(line.placement.method, "gnss+learned-camera-up");
  ASSERT_TRUE(line.absolute);
  EXPECT_LT(line.absolute->keyframe_horizontal_rms_m, 1.0);
  const std::vector<std::string> summary = geo.Summary();
  ASSERT_EQ(summary.size(), 3u);
  EXPECT_NE(summary[1].find("map-0 (600 frames) placed by"), std::string::npos) << summary[1];
  EXPECT_NE(summary[2].find("submap-0-3 (200 frames) placed by"), std::string::npos) << summary[2];
  EXPECT_NE(summary[2].find("with the cameras' up"), std::string::npos) << summary[2];
}

TEST(GeoReferenceRun, WritesTheTrajectoryInWgs84AndHowEachMapWasPlaced) {
  const FlownRun run = MakeRun();
  const RunGeoReference geo = GeoReferenceRun(run.poses, 0, run.gnss, run.truth, GeoReferenceOptions());
  testing::TempDir dir;
  WriteGeoOutputs((dir / "geo"), geo, run.poses);
  std::ifstream csv(dir.path() / "geo" / "trajectory_wgs84.csv");
  int lines = 0;
  for (std::string line; std::getline(csv, line);) ++lines;
  EXPECT_EQ(lines, 1 + 800);  // every placed map's frames
  std::ifstream in(dir.path() / "geo" / "georeference.json");
  const nlohmann::json json = nlohmann::json::parse(in);
  EXPECT_EQ(json["maps"].size(), 2u);
  EXPECT_EQ(json["maps"][0]["placed_by"], "gnss");
  EXPECT_EQ(json["maps"][1]["placed_by"], "gnss+learned-camera-up");
  EXPECT_TRUE(std::filesystem::exists(dir.path() / "geo" / "trajectory.geojson"));
  EXPECT_TRUE(std::filesystem::exists(dir.path() / "geo" / "trajectory.kml"));
}

TEST(GeoReferenceRun, WritesAPlacedMapsPointsInEnuMetres) {
  const FlownRun run = MakeRun();
  const RunGeoReference geo = GeoReferenceRun(run.poses, 0, run.gnss, run.truth, GeoReferenceOptions());
  ASSERT_TRUE(geo.maps[0].map.component == 0 && geo.maps[0].placement.placed);
  // Two points of the largest map's frame (two of its cameras' centres), where its placement puts them.
  const Sim3d& enu_from_map = geo.maps[0].placement.enu_from_map;
  std::vector<ColouredPoint> points(2);
  ASSERT_EQ(run.poses[0].component, 0);
  ASSERT_EQ(run.poses[300].component, 0);
  points[0].position = run.poses[0].world_from_cam.translation.cast<float>();
  points[1].position = run.poses[300].world_from_cam.translation.cast<float>();
  points[1].red = 7;
  testing::TempDir dir;
  const std::string path = (dir.path() / "map_enu.ply").string();
  ASSERT_TRUE(WriteMapInEnu(path, geo, 0, points));
  const std::vector<ColouredPoint> written = ReadPly(path);
  ASSERT_EQ(written.size(), 2u);
  for (size_t i = 0; i < 2; ++i) {
    const Eigen::Vector3d expected = enu_from_map * points[i].position.cast<double>();
    EXPECT_LT((written[i].position.cast<double>() - expected).norm(), 1e-3) << i;
    // ...which is where the truth has them, within a fix's noise (2 m horizontal, 3 m vertical),
    // not in the map's units (a twentieth of a metre) nor tens of metres off.
    const Eigen::Vector3d truth = kMap0FromEnu.Inverse() * points[i].position.cast<double>();
    EXPECT_LT((written[i].position.cast<double>() - truth).norm(), 3.0) << i;
  }
  EXPECT_EQ(written[1].red, 7);
  // Metres, not the map's units: the placement's scale is not 1 (the map is in median depths).
  EXPECT_GT(std::abs(enu_from_map.scale - 1.0), 0.01);
  std::ifstream in(path);
  std::string header((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(header.find("comment frame: east-north-up, metres"), std::string::npos);
  // No map placed: nothing written.
  RunGeoReference unplaced = geo;
  for (MapGeoReference& m : unplaced.maps) m.placement.placed = false;
  EXPECT_FALSE(WriteMapInEnu((dir.path() / "none.ply").string(), unplaced, 0, points));
  EXPECT_FALSE(std::filesystem::exists(dir.path() / "none.ply"));
}

// The same points as LAS in WGS 84 / UTM: each where its ENU position lies on Earth, in the
// origin's zone (48 N, 11 E: zone 32 north, EPSG 32632), to the millimetre.
TEST(GeoReferenceRun, WritesAPlacedMapsPointsAsLasInUtm) {
  const FlownRun run = MakeRun();
  const RunGeoReference geo = GeoReferenceRun(run.poses, 0, run.gnss, run.truth, GeoReferenceOptions());
  ASSERT_TRUE(geo.maps[0].placement.placed);
  std::vector<ColouredPoint> points(2);
  points[0].position = run.poses[0].world_from_cam.translation.cast<float>();
  points[1].position = run.poses[300].world_from_cam.translation.cast<float>();
  points[1].green = 9;
  testing::TempDir dir;
  const std::string path = (dir.path() / "map_utm.las").string();
  ASSERT_TRUE(WriteMapLas(path, geo, 0, points));
  const LasCloud cloud = ReadLas(path);
  EXPECT_EQ(cloud.epsg, 32632);
  ASSERT_EQ(cloud.points.size(), 2u);
  const LocalTangentPlane plane(geo.origin);
  for (size_t i = 0; i < 2; ++i) {
    const GeodeticPoint expected =
        plane.ToGeodetic(geo.maps[0].placement.enu_from_map * points[i].position.cast<double>());
    const Eigen::Vector2d utm = ToUtm(expected, UtmZoneOf(geo.origin));
    EXPECT_LT((cloud.points[i].position.head<2>() - utm).norm(), 0.002) << i;
    EXPECT_NEAR(cloud.points[i].position.z(), expected.height_m, 0.002);
  }
  EXPECT_EQ(cloud.points[1].green, 9);
  // 11 E is 2 degrees east of zone 32's central meridian (9 E): about 149 km east of its 500 km.
  EXPECT_NEAR(cloud.points[0].position.x(), 649'000, 2'000);
  EXPECT_NEAR(cloud.points[0].position.y(), 5'318'000, 5'000);
  RunGeoReference unplaced = geo;
  for (MapGeoReference& m : unplaced.maps) m.placement.placed = false;
  EXPECT_FALSE(WriteMapLas((dir.path() / "none.las").string(), unplaced, 0, points));
}

// The largest map's COLMAP model in ENU metres: its cameras where the placement puts them (and
// the truth has them, within a fix's noise), its point with them, and every feature where the
// moved camera sees the moved point, as before (a similarity changes no projection).
TEST(GeoReferenceRun, WritesAPlacedMapsColmapModelInEnuMetres) {
  const FlownRun run = MakeRun();
  const RunGeoReference geo = GeoReferenceRun(run.poses, 0, run.gnss, run.truth, GeoReferenceOptions());
  ASSERT_TRUE(geo.maps[0].placement.placed);
  const Sim3d& enu_from_map = geo.maps[0].placement.enu_from_map;
  ColmapModel model;
  model.cameras[1] = Camera::Pinhole(640, 480, 500, 500, 320, 240);
  const Rigid3d& first = run.poses[0].world_from_cam;
  // A point 30 units ahead of the first camera (a nadir camera 70 m up at 0.05 units a metre:
  // 3.5 units), and the second camera a unit beside it, turned a little.
  const Eigen::Vector3d point = first * Eigen::Vector3d(0.2, -0.1, 3.5);
  const Rigid3d second =
      first * Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.05, Eigen::Vector3d::UnitX())), {1.0, 0, 0});
  int id = 0;
  for (const Rigid3d& world_from_cam : {first, second}) {
    ColmapImage image;
    image.id = ++id;
    image.cam_from_world = world_from_cam.Inverse();
    image.name = "frame" + std::to_string(id) + ".jpg";
    image.features = {*model.cameras[1].Project(image.cam_from_world * point)};
    image.point_ids = {1};
    model.images.push_back(image);
  }
  ColmapPoint colmap_point;
  colmap_point.id = 1;
  colmap_point.position = point;
  colmap_point.track = {{1, 0}, {2, 0}};
  model.points.push_back(colmap_point);
  ASSERT_LT(ReprojectionRms(model), 1e-6);

  testing::TempDir dir;
  const std::string out = (dir.path() / "colmap_enu").string();
  ASSERT_TRUE(WriteColmapModelInEnu(out, geo, 0, model));
  const ColmapModel written = ReadColmapModel(out);
  ASSERT_EQ(written.images.size(), 2u);
  ASSERT_EQ(written.points.size(), 1u);
  EXPECT_LT((written.points[0].position - enu_from_map * point).norm(), 1e-3);
  for (size_t i = 0; i < 2; ++i) {
    const Eigen::Vector3d centre = enu_from_map * model.images[i].cam_from_world.CentreInWorld();
    EXPECT_LT((written.images[i].cam_from_world.CentreInWorld() - centre).norm(), 1e-3) << i;
  }
  // In metres where the truth has the first camera, not in the map's units.
  EXPECT_LT((written.images[0].cam_from_world.CentreInWorld() - TrueCamera(0).translation).norm(), 3.0);
  EXPECT_LT(ReprojectionRms(written), 1e-3);
  std::ifstream in(std::filesystem::path(out) / "georeference.txt");
  const std::string frame((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(frame.find("east-north-up, metres"), std::string::npos) << frame;
  EXPECT_NE(frame.find("latitude 48.0"), std::string::npos) << frame;
  // No map placed: nothing written.
  RunGeoReference unplaced = geo;
  for (MapGeoReference& m : unplaced.maps) m.placement.placed = false;
  EXPECT_FALSE(WriteColmapModelInEnu((dir.path() / "none").string(), unplaced, 0, model));
  EXPECT_FALSE(std::filesystem::exists(dir.path() / "none"));
}

TEST(GeoReferenceRun, SaysWhyAMapWasNotPlaced) {
  FlownRun run = MakeRun();
  GeoReferenceOptions options;
  options.camera_up_axis = "none";
  const RunGeoReference geo = GeoReferenceRun(run.poses, 0, run.gnss, run.truth, options);
  ASSERT_EQ(geo.maps.size(), 2u);
  EXPECT_FALSE(geo.maps[1].placement.placed);
  EXPECT_NE(geo.Summary()[2].find("submap-0-3 (200 frames) not placed: its fixes lie along a line"), std::string::npos)
      << geo.Summary()[2];
  EXPECT_NE(geo.ToJson()["maps"][1]["why_not"].get<std::string>().find("line"), std::string::npos);
}

TEST(GeoReferenceRun, RefusesATrackWithoutAUsableFix) {
  FlownRun run = MakeRun();
  for (GnssFix& f : run.gnss.fixes) f.type = GnssFixType::kNone;
  EXPECT_THROW(GeoReferenceRun(run.poses, 0, run.gnss, run.truth, GeoReferenceOptions()), Error);
}

}  // namespace
}  // namespace stitch
