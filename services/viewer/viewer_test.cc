// The viewer's state (what the page is sent) from constructed messages, and its web server
// against hostile requests: only GET and HEAD of its own paths, WebSockets only from its own
// origin and only as many as max_pages.

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <functional>
#include <limits>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "services/common/bus.h"
#include "services/common/convert.h"
#include "services/common/secret_file.h"
#include "services/viewer/viewer_server.h"
#include "services/viewer/viewer_state.h"
#include "stitch/mosaic/live_mosaic.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"
#include "stitch/util/ids.h"
#include "stitch/util/time.h"
#include "tests/test_process.h"

namespace stitch {
namespace {

const SubmapId kFirst = MakeSubmapId(0, 1), kSecond = MakeSubmapId(0, 2), kAlone = MakeSubmapId(0, 3);

stitch::global_map_t GlobalMap() {
  stitch::global_map_t m{};
  m.header.agent = "uav0";
  m.revision = 1;
  const Sim3d moved(2.0, Eigen::Quaterniond(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ())), {10, 0, 0});
  for (const auto& [id, component, pose] :
       {std::tuple{kFirst, 0, Sim3d()}, std::tuple{kSecond, 0, moved}, std::tuple{kAlone, 1, Sim3d()}}) {
    stitch::submap_placement_t p{};
    p.agent = "uav0";
    p.submap_id = id.value;
    p.component = component;
    p.world_from_submap = ToMessage(pose);
    p.num_keyframes = 10;
    p.num_points = 100;
    p.closed = id != kAlone;
    m.submaps.push_back(p);
    for (int k = 0; k < 3; ++k) {
      stitch::trajectory_pose_t t{};
      t.frame_index = 10 * k;
      t.submap_id = id.value;
      t.component = component;
      t.is_keyframe = true;
      t.world_from_cam = ToMessage(Sim3d(1.0, Eigen::Quaterniond::Identity(), Eigen::Vector3d(k, 0, 0)));
      m.trajectory.push_back(t);
    }
  }
  m.num_submaps = 3;
  m.num_poses = static_cast<int32_t>(m.trajectory.size());
  stitch::submap_edge_t merged{}, refused{};
  merged.submap_a = kFirst.value;
  merged.submap_b = kSecond.value;
  merged.strength = 42.5;
  merged.connected_frames = 5;
  merged.in_spanning_tree = true;
  merged.b_from_a = ToMessage(Sim3d());
  refused = merged;
  refused.submap_b = kAlone.value;
  refused.strength = 12;
  refused.in_spanning_tree = false;
  refused.refused = "one connected frame";
  m.edges = {merged, refused};
  m.num_edges = 2;
  m.merge_log = {"submap 0:2 closed\t0:1 0:2\t0:3\t0:1+0:2 0:3"};
  m.num_log_lines = 1;
  return m;
}

TEST(ViewerState, TheMapHoldsEverySubmapItsTrajectoryTheEdgesAndTheLog) {
  ViewerState state(1000);
  std::string why;
  ASSERT_TRUE(state.OnGlobalMap(GlobalMap(), &why)) << why;
  const nlohmann::json map = nlohmann::json::parse(state.MapJson());
  ASSERT_EQ(map["submaps"].size(), 3u);
  EXPECT_EQ(map["submaps"][0]["id"], "0:1");
  EXPECT_EQ(map["submaps"][0]["colour"], SubmapColour(0));
  EXPECT_EQ(map["submaps"][1]["colour"], SubmapColour(1));
  EXPECT_EQ(map["submaps"][0]["trajectory"].size(), 3u);
  EXPECT_TRUE(map["submaps"][1]["merged"]);
  EXPECT_FALSE(map["submaps"][2]["merged"]) << "0:3 is a merged map on its own";
  EXPECT_EQ(map["merged_maps"], 1);
  EXPECT_EQ(map["keyframes"], 30);
  ASSERT_EQ(map["edges"].size(), 2u);
  EXPECT_TRUE(map["edges"][0]["tree"]);
  EXPECT_DOUBLE_EQ(map["edges"][0]["C"].get<double>(), 42.5);
  EXPECT_EQ(map["edges"][1]["refused"], "one connected frame");
  ASSERT_EQ(map["merge_log"].size(), 1u);
  EXPECT_EQ(state.map_revision(), 1);
  // An older revision from the same merger changes nothing.
  stitch::global_map_t older = GlobalMap();
  older.revision = 0;
  EXPECT_TRUE(state.OnGlobalMap(older, &why));
  EXPECT_EQ(state.map_revision(), 1);
}

TEST(ViewerState, TheCameraIsPlacedInItsMergedMapBySubmapPlacement) {
  ViewerState state(1000);
  std::string why;
  ASSERT_TRUE(state.OnGlobalMap(GlobalMap(), &why));
  const Rigid3d submap_from_cam(Eigen::Quaterniond::Identity(), {1, 0, 0});
  stitch::frame_pose_t pose = FramePoseMessage(7, 700, kSecond, submap_from_cam.Inverse(), KeyframeId(), std::nullopt);
  pose.header.agent = "uav0";
  ASSERT_TRUE(state.OnPose(pose, &why)) << why;
  stitch::tracking_status_t status{};
  status.header.agent = "uav0";
  status.frame_index = 7;
  status.state = stitch::tracking_status_t::STATE_OK;
  status.submap_id = kSecond.value;
  for (int i = 0; i < 10; ++i) ASSERT_TRUE(state.OnTrackingStatus(status, 100.0 + 0.1 * i, &why));
  const nlohmann::json live = nlohmann::json::parse(state.LiveJson(101.0));
  const nlohmann::json& camera = live["aircraft"]["uav0"]["camera"];
  EXPECT_EQ(camera["component"], 0);
  // 2 * Rz(90) * (1, 0, 0) + (10, 0, 0) = (10, 2, 0)
  EXPECT_NEAR(camera["position"][0].get<double>(), 10, 1e-5);
  EXPECT_NEAR(camera["position"][1].get<double>(), 2, 1e-5);
  const nlohmann::json& tracking = live["aircraft"]["uav0"]["tracking"];
  EXPECT_EQ(tracking["state"], "OK");
  EXPECT_NEAR(tracking["fps"].get<double>(), 10, 0.01);
  // A pose of a submap the ground has not placed yet: no merged map.
  pose.submap_id = MakeSubmapId(0, 9).value;
  pose.frame_index = 8;
  ASSERT_TRUE(state.OnPose(pose, &why));
  EXPECT_TRUE(nlohmann::json::parse(state.LiveJson(101.0))["aircraft"]["uav0"]["camera"]["component"].is_null());
}

TEST(ViewerState, BothSidesLinkBridgesAreShownEachByWhatItSends) {
  ViewerState state(1000);
  std::string why;
  stitch::link_status_t down{}, up{};
  down.header.agent = up.header.agent = "uav0";
  down.forward = "uav0/(SUBMAP|SEQUENCE|TRACKING_STATUS|POSE|GNSS|SERVICE|LINK_STATUS)";
  down.backlog_s = 12.5;
  up.forward = "uav0/SUBMAP_REQUEST";
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(state.OnLinkStatus(down, &why)) << why;
    ASSERT_TRUE(state.OnLinkStatus(up, &why)) << why;
  }
  const nlohmann::json links = nlohmann::json::parse(state.LiveJson(0))["aircraft"]["uav0"]["links"];
  ASSERT_EQ(links.size(), 2u) << links.dump();
  EXPECT_DOUBLE_EQ(links[0]["backlog_s"].get<double>(), 12.5);
  EXPECT_EQ(links[1]["forward"], "uav0/SUBMAP_REQUEST");
  // A stranger's bridges beyond a few are refused rather than kept.
  for (int i = 0; i < 2; ++i) {
    up.forward = "uav0/OTHER" + std::to_string(i);
    ASSERT_TRUE(state.OnLinkStatus(up, &why));
  }
  up.forward = "uav0/ONE_TOO_MANY";
  EXPECT_FALSE(state.OnLinkStatus(up, &why));
}

// Submaps no view joins, joined where the aircraft's GNSS places their maps: the edge says so.
TEST(ViewerState, AGnssJunctionIsShownAsOne) {
  ViewerState state(1000);
  std::string why;
  stitch::global_map_t map = GlobalMap();
  map.edges[1].refused = "";
  map.edges[1].strength = 0;
  map.edges[1].connected_frames = 0;
  map.edges[1].in_spanning_tree = true;
  map.edges[1].gnss_sigma_m = 0.72;
  for (auto& submap : map.submaps) submap.component = 0;
  ASSERT_TRUE(state.OnGlobalMap(map, &why)) << why;
  const nlohmann::json shown = nlohmann::json::parse(state.MapJson());
  EXPECT_EQ(shown["merged_maps"], 1);
  EXPECT_TRUE(shown["submaps"][2]["merged"]);
  EXPECT_TRUE(shown["edges"][1]["tree"]);
  EXPECT_DOUBLE_EQ(shown["edges"][1]["gnss_sigma_m"].get<double>(), 0.72);
  EXPECT_DOUBLE_EQ(shown["edges"][0]["gnss_sigma_m"].get<double>(), 0.0);
}

// #42: where the fixes place a merged map, as the page's scale bar and north arrow need it.
stitch::map_on_earth_t OnEarth(const Sim3d& enu_from_world) {
  stitch::map_on_earth_t e{};
  e.component = 0;
  e.enu_from_world = ToMessage(enu_from_world);
  e.origin_latitude_deg = 47.39;
  e.origin_longitude_deg = 8.51;
  e.origin_height_m = 450;
  e.inlier_fixes = 240;
  e.horizontal_rms_m = 1.9;
  return e;
}

TEST(ViewerState, AMapOnEarthGivesItsMetresAndItsNorth) {
  ViewerState state(1000);
  std::string why;
  stitch::global_map_t map = GlobalMap();
  ASSERT_TRUE(state.OnGlobalMap(map, &why)) << why;
  EXPECT_TRUE(nlohmann::json::parse(state.MapJson())["on_earth"].empty()) << "no fixes, nothing on Earth";
  // A camera frame (x east, y south, z down) 25 m per map unit: the map's -y is north, -z up.
  map.revision = 2;
  map.on_earth = {OnEarth(Sim3d(25.0, Eigen::Quaterniond(Eigen::Vector3d(1, -1, -1).asDiagonal().toDenseMatrix()),
                                Eigen::Vector3d(3, 4, 5)))};
  map.num_on_earth = 1;
  ASSERT_TRUE(state.OnGlobalMap(map, &why)) << why;
  const nlohmann::json shown = nlohmann::json::parse(state.MapJson());
  ASSERT_EQ(shown["on_earth"].size(), 1u);
  const nlohmann::json& earth = shown["on_earth"][0];
  EXPECT_EQ(earth["component"], 0);
  EXPECT_DOUBLE_EQ(earth["metres_per_unit"].get<double>(), 25.0);
  const auto near = [](const nlohmann::json& v, const Eigen::Vector3d& expected) {
    return (Eigen::Vector3d(v[0].get<double>(), v[1].get<double>(), v[2].get<double>()) - expected).norm() < 1e-9;
  };
  EXPECT_TRUE(near(earth["east"], {1, 0, 0})) << earth.dump();
  EXPECT_TRUE(near(earth["north"], {0, -1, 0})) << earth.dump();
  EXPECT_TRUE(near(earth["up"], {0, 0, -1})) << earth.dump();
  EXPECT_DOUBLE_EQ(earth["origin"][0].get<double>(), 47.39);
  EXPECT_EQ(earth["fixes"], 240);
  // The whole placement, for the mosaic view of the maps on Earth to draw each map's paths.
  EXPECT_DOUBLE_EQ(earth["enu_from_world"]["scale"].get<double>(), 25.0);
  EXPECT_TRUE(near(earth["enu_from_world"]["translation"], {3, 4, 5})) << earth.dump();
  EXPECT_DOUBLE_EQ(earth["enu_from_world"]["rotation_wxyz"][1].get<double>(), 1.0) << earth.dump();

  // A place on Earth that is none is refused, the map shown before kept.
  for (const auto& spoil : std::vector<std::function<void(stitch::map_on_earth_t*)>>{
           [](stitch::map_on_earth_t* e) { e->enu_from_world.scale = 0; },
           [](stitch::map_on_earth_t* e) { e->origin_latitude_deg = 91; },
           [](stitch::map_on_earth_t* e) { e->horizontal_rms_m = std::numeric_limits<double>::quiet_NaN(); },
           [](stitch::map_on_earth_t* e) { e->component = -1; }}) {
    stitch::global_map_t bad = map;
    bad.revision = 3;
    spoil(&bad.on_earth[0]);
    EXPECT_FALSE(state.OnGlobalMap(bad, &why));
  }
  EXPECT_EQ(state.refused(), 4);
  EXPECT_EQ(nlohmann::json::parse(state.MapJson())["on_earth"].size(), 1u);
}

// A PNG tile_px a side, as the merger sends a mosaic tile.
std::vector<uint8_t> TilePng(int tile_px, uint8_t grey) {
  std::vector<uint8_t> png;
  cv::imencode(".png", cv::Mat(tile_px, tile_px, CV_8UC4, cv::Scalar(grey, grey, grey, 255)), png);
  return png;
}

stitch::mosaic_tile_t MosaicTile(int64_t revision, int col, int row, int64_t version) {
  stitch::mosaic_tile_t m{};
  m.header.agent = "uav0";
  m.revision = revision;
  m.frame_submap = kFirst.value;
  m.ground_from_map = ToMessage(Sim3d());
  m.gsd = 0.01;
  m.tile_px = 32;
  m.col = col;
  m.row = row;
  m.version = version;
  m.newest_picture_utime = 1'000'000;
  m.png = TilePng(32, 100);
  m.num_bytes = static_cast<int32_t>(m.png.size());
  return m;
}

// #43: the merger's live mosaic on the page: the tiles of the newest revision, each at its newest
// version, listed in the live update and served as PNG; what cannot be a tile is refused.
TEST(ViewerState, TheMosaicHoldsTheNewestTilesAndRefusesWhatIsNoTile) {
  ViewerState state(1000);
  std::string why;
  ASSERT_TRUE(state.OnMosaicTile(MosaicTile(1, 0, 0, 1), 1'500'000, &why)) << why;
  ASSERT_TRUE(state.OnMosaicTile(MosaicTile(1, -1, 2, 2), 2'000'000, &why)) << why;
  stitch::mosaic_tile_t emptied = MosaicTile(1, -1, 2, 3);  // nothing drawn there any more
  emptied.png.clear();
  emptied.num_bytes = 0;
  ASSERT_TRUE(state.OnMosaicTile(emptied, 2'000'000, &why)) << why;
  ASSERT_TRUE(state.OnMosaicTile(MosaicTile(1, 0, 0, 1), 2'000'000, &why));  // an older copy: kept the newer
  nlohmann::json mosaic = nlohmann::json::parse(state.LiveJson(0))["mosaic"];
  EXPECT_EQ(mosaic["tiles"], nlohmann::json::parse("[[0, 0, 1]]"));
  EXPECT_EQ(mosaic["frame"], "0:1");
  // One sample per update that laid pictures: the first tile's (the others carry the same picture).
  EXPECT_NEAR(mosaic["latency_max_s"].get<double>(), 0.5, 1e-9);
  EXPECT_NEAR(mosaic["latency_median_s"].get<double>(), 0.5, 1e-9);
  ASSERT_NE(state.MosaicTilePng(0, 0), nullptr);
  EXPECT_EQ(state.MosaicTilePng(-1, 2), nullptr);
  // A new revision (the mosaic started over) replaces every tile.
  ASSERT_TRUE(state.OnMosaicTile(MosaicTile(2, 5, 5, 9), 2'000'000, &why));
  mosaic = nlohmann::json::parse(state.LiveJson(0))["mosaic"];
  EXPECT_EQ(mosaic["tiles"], nlohmann::json::parse("[[5, 5, 9]]"));
  EXPECT_EQ(state.MosaicTilePng(0, 0), nullptr);
  // What is no tile.
  const int64_t refused_before = state.refused();
  std::vector<stitch::mosaic_tile_t> hostile(7, MosaicTile(2, 1, 1, 10));
  hostile[0].png = TilePng(64, 1);   // another side than it says
  hostile[1].png.assign(100, 0xAB);  // no PNG
  hostile[2].gsd = std::numeric_limits<double>::quiet_NaN();
  hostile[3].ground_from_map.scale = -1;
  hostile[4].col = 2'000'000;
  hostile[5].tile_px = 1 << 20;
  hostile[6].version = 0;
  for (auto& m : hostile) {
    m.num_bytes = static_cast<int32_t>(m.png.size());
    EXPECT_FALSE(state.OnMosaicTile(m, 2'000'000, &why));
    EXPECT_FALSE(why.empty());
  }
  EXPECT_EQ(state.refused(), refused_before + 7);
  EXPECT_EQ(state.MosaicTilePng(1, 1), nullptr);
  // A mosaic of the maps the fixes place, in their frame: its frame is the Earth's.
  stitch::mosaic_tile_t on_earth = MosaicTile(3, 0, 0, 11);
  on_earth.frame_submap = LiveMosaic::kFrameOnEarth;
  ASSERT_TRUE(state.OnMosaicTile(on_earth, 2'000'000, &why)) << why;
  EXPECT_EQ(nlohmann::json::parse(state.LiveJson(0))["mosaic"]["frame"], "earth");
}

TEST(ViewerState, ContentThatCannotBeDrawnIsRefusedAndCounted) {
  ViewerState state(1000);
  std::string why;
  stitch::global_map_t map = GlobalMap();
  map.submaps[1].world_from_submap.rotation_wxyz[0] = 40;  // not a unit quaternion
  EXPECT_FALSE(state.OnGlobalMap(map, &why));
  EXPECT_NE(why.find("unit quaternion"), std::string::npos) << why;
  map = GlobalMap();
  map.edges[0].strength = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(state.OnGlobalMap(map, &why));
  map = GlobalMap();
  map.edges[1].gnss_sigma_m = -std::numeric_limits<double>::infinity();
  EXPECT_FALSE(state.OnGlobalMap(map, &why));
  EXPECT_NE(why.find("GNSS"), std::string::npos) << why;

  stitch::map_cloud_t cloud{};
  cloud.header.agent = "uav0";
  cloud.revision = 1;
  cloud.num_submaps = 1;
  cloud.submap_ids = {kFirst.value};
  cloud.components = {0};
  cloud.point_counts = {5};  // five points, two given
  cloud.positions = {1, 2, 3, 4, 5, 6};
  cloud.num_coordinates = 6;
  EXPECT_FALSE(state.OnMapCloud(cloud, &why));
  EXPECT_NE(why.find("add up"), std::string::npos) << why;
  cloud.point_counts = {-1};
  EXPECT_FALSE(state.OnMapCloud(cloud, &why));

  stitch::frame_pose_t pose{};
  pose.header.agent = "uav0";
  pose.submap_id = kFirst.value;
  pose.cam_from_submap[0] = std::numeric_limits<float>::infinity();
  EXPECT_FALSE(state.OnPose(pose, &why));

  stitch::link_status_t link{};
  link.header.agent = "uav0";
  link.backlog_s = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(state.OnLinkStatus(link, &why));

  stitch::tracking_status_t status{};
  status.header.agent = "uav0";
  status.frame_index = -5;
  EXPECT_FALSE(state.OnTrackingStatus(status, 0, &why));
  // Texts that are no UTF-8 (the bus fuzz test's find: the push thread threw on them) are shown
  // with replacement characters.
  status.frame_index = 3;
  status.detail = "\x80\xff broken";
  link.backlog_s = 0;
  link.forward = "uav0/\xc3(";
  ASSERT_TRUE(state.OnTrackingStatus(status, 0, &why));
  ASSERT_TRUE(state.OnLinkStatus(link, &why));
  EXPECT_NO_THROW(nlohmann::json::parse(state.LiveJson(0)));
  EXPECT_EQ(state.refused(), 8);
  EXPECT_EQ(state.map_revision(), 0);
  EXPECT_EQ(state.cloud_revision(), 0);
}

TEST(ViewerState, TheCloudIsThinnedToThePagesBoundAndLeavesOutNonFinitePoints) {
  ViewerState state(/*max_page_points=*/50);
  std::string why;
  ASSERT_TRUE(state.OnGlobalMap(GlobalMap(), &why));
  stitch::map_cloud_t cloud{};
  cloud.header.agent = "uav0";
  cloud.revision = 1;
  cloud.num_submaps = 2;
  cloud.submap_ids = {kFirst.value, kAlone.value};
  cloud.components = {0, 1};
  cloud.point_counts = {100, 100};
  for (int i = 0; i < 200; ++i) cloud.positions.insert(cloud.positions.end(), {float(i), 0.f, 1.f});
  cloud.positions[3 * 4] = std::numeric_limits<float>::quiet_NaN();  // point 4, kept by the thinning
  cloud.num_coordinates = static_cast<int32_t>(cloud.positions.size());
  cloud.points_in_maps = 200;
  ASSERT_TRUE(state.OnMapCloud(cloud, &why)) << why;
  const std::string bytes = state.CloudBinary();
  uint32_t header[4];
  std::memcpy(header, bytes.data(), sizeof(header));
  EXPECT_EQ(std::string(bytes.data(), 4), "STCL");
  const uint32_t n = header[2];
  EXPECT_EQ(n, 49u) << "every 4th of 200 points (50), less the NaN one";
  ASSERT_EQ(bytes.size(), 16 + 16 * n);
  float first[3];
  std::memcpy(first, bytes.data() + 16, sizeof(first));
  EXPECT_EQ(first[0], 0.f);
  const uint8_t* colours = reinterpret_cast<const uint8_t*>(bytes.data()) + 16 + 12 * n;
  const uint8_t* components = colours + 3 * n;
  EXPECT_EQ(components[0], 0);
  EXPECT_EQ(components[n - 1], 1) << "the last points are 0:3's, a merged map of its own";
  EXPECT_NE(std::memcmp(colours, colours + 3 * (n - 1), 3), 0) << "two submaps, two colours";
}

// --- The web server ---------------------------------------------------------------------------

std::string Exchange(int port, const std::string& request, bool until_close = true) {
  return testing::HttpExchange(port, request, until_close);
}

std::string StatusLine(const std::string& reply) {
  return reply.substr(0, reply.find("\r\n"));
}

std::string WebSocketRequest(int port, const std::string& origin) {
  return "GET /live HTTP/1.1\r\nHost: 127.0.0.1:" + std::to_string(port) +
         "\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
         "Sec-WebSocket-Version: 13\r\nOrigin: " +
         origin + "\r\n\r\n";
}

// The tests' servers take their ports from bus::UnusedTcpPort: never one a server holds.
TEST(ViewerServer, AnUnusedTestPortIsNeverOneAServerHolds) {
  ViewerState state(1000);
  ViewerOptions options;
  options.port = bus::UnusedTcpPort();
  ViewerServer server(options, &state);
  ASSERT_EQ(StatusLine(Exchange(options.port, "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")), "HTTP/1.1 200 OK");
  for (int i = 0; i < 50; ++i) EXPECT_NE(bus::UnusedTcpPort(options.port, 2), options.port);
}

TEST(ViewerServer, ServesThePageAndThreeJsAndNothingElse) {
  ViewerState state(1000);
  ViewerOptions options;
  options.port = bus::UnusedTcpPort();
  ViewerServer server(options, &state);
  const int port = options.port;
  const std::string page = Exchange(port, "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
  EXPECT_EQ(StatusLine(page), "HTTP/1.1 200 OK");
  EXPECT_NE(page.find("/three/three.min.js"), std::string::npos);
  EXPECT_NE(page.find("Content-Security-Policy: default-src 'self'"), std::string::npos);
  EXPECT_EQ(StatusLine(Exchange(port, "GET /three/three.min.js HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")),
            "HTTP/1.1 200 OK");
  EXPECT_EQ(StatusLine(Exchange(port, "GET /three/OrbitControls.js HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")),
            "HTTP/1.1 200 OK");
  EXPECT_EQ(StatusLine(Exchange(port, "GET /viewer.js HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")), "HTTP/1.1 200 OK");
  const std::string json = Exchange(port, "GET /state.json HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
  ASSERT_EQ(StatusLine(json), "HTTP/1.1 200 OK");
  EXPECT_NO_THROW(nlohmann::json::parse(json.substr(json.find("\r\n\r\n") + 4)));
  EXPECT_EQ(StatusLine(Exchange(port, "GET /cloud.bin HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")), "HTTP/1.1 200 OK");
  // Hostile requests: other paths (a way out of any folder among them), other methods, garbage.
  for (const char* path : {"/../../../etc/passwd", "/three/../../../../etc/passwd", "/%2e%2e/%2e%2e/etc/passwd",
                           "/etc/passwd", "/live.json", "/three/"}) {
    const std::string reply = Exchange(port, std::string("GET ") + path + " HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
    EXPECT_EQ(reply.find("root:"), std::string::npos) << path;
    EXPECT_NE(StatusLine(reply).substr(9, 3), "200") << path << ": " << StatusLine(reply);
  }
  EXPECT_EQ(StatusLine(Exchange(port, "POST / HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 3\r\n\r\nabc")),
            "HTTP/1.1 405 Method Not Allowed");
  EXPECT_EQ(StatusLine(Exchange(port, "GET /live HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")), "HTTP/1.1 400 Bad Request");
  Exchange(port, "\x16\x03\x01\x02\x00garbage\r\n\r\n");
  Exchange(port, "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Long: " + std::string(200000, 'a') + "\r\n\r\n");
  Exchange(port, "GET / HTTP/1.1\r\n");  // never finished: the request timeout frees the thread
  // ...and it still serves.
  EXPECT_EQ(StatusLine(Exchange(port, "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")), "HTTP/1.1 200 OK");
  EXPECT_GE(server.requests_refused(), 8);  // 6 paths, a method, a plain GET of /live
}

// The mosaic's tiles: /mosaic/COL_ROW.png for a tile held, nothing (204) for one not held, and
// every other form refused.
TEST(ViewerServer, ServesTheMosaicsTilesByTheirPlace) {
  ViewerState state(1000);
  std::string why;
  ASSERT_TRUE(state.OnMosaicTile(MosaicTile(1, -3, 4, 1), 2'000'000, &why)) << why;
  ViewerOptions options;
  options.port = bus::UnusedTcpPort();
  ViewerServer server(options, &state);
  const auto get = [&](const std::string& path) {
    return Exchange(options.port, "GET " + path + " HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
  };
  const std::string tile = get("/mosaic/-3_4.png?v=1");
  EXPECT_EQ(StatusLine(tile), "HTTP/1.1 200 OK");
  EXPECT_NE(tile.find("Content-Type: image/png"), std::string::npos);
  EXPECT_NE(tile.find("\x89PNG"), std::string::npos);
  EXPECT_EQ(StatusLine(get("/mosaic/0_0.png")), "HTTP/1.1 204 No Content");
  const int64_t refused_before = server.requests_refused();
  for (const char* path : {"/mosaic/-3_4.pngx", "/mosaic/+-3_4.png", "/mosaic/-3_04.png", "/mosaic/../state.json",
                           "/mosaic/", "/mosaic/99999999999_1.png"}) {
    EXPECT_EQ(StatusLine(get(path)), "HTTP/1.1 404 Not Found") << path;
  }
  EXPECT_EQ(server.requests_refused(), refused_before + 6);
}

// DNS rebinding: a page of evil.example whose name was made to resolve to this machine sends
// Host (and Origin) evil.example. Only hosts that name this machine are answered: localhost, an
// IP address (with any port: an SSH tunnel maps it), viewer.allowed_hosts.
TEST(ViewerServer, AnswersOnlyHostsThatNameThisMachine) {
  ViewerState state(1000);
  ViewerOptions options;
  options.port = bus::UnusedTcpPort();
  options.allowed_hosts = "ground.local, Station";
  ViewerServer server(options, &state);
  const int port = options.port;
  const std::string p = std::to_string(port);
  const auto get = [&](const std::string& host_line) {
    return StatusLine(Exchange(port, "GET /state.json HTTP/1.1\r\n" + host_line + "\r\n"));
  };
  for (const std::string& host :
       std::vector<std::string>{"127.0.0.1:" + p, "localhost:" + p, "LOCALHOST:9000", "192.168.1.5:" + p, "[::1]:" + p,
                                "ground.local:" + p, "station"}) {
    EXPECT_EQ(get("Host: " + host + "\r\n"), "HTTP/1.1 200 OK") << host;
  }
  const int64_t refused_before = server.requests_refused();
  for (const std::string& host :
       std::vector<std::string>{"evil.example:" + p, "evil.example", "127.0.0.1.evil.example:" + p,
                                "localhost.evil.example", "ground.local.evil.example"}) {
    EXPECT_EQ(get("Host: " + host + "\r\n"), "HTTP/1.1 403 Forbidden") << host;
  }
  EXPECT_EQ(get(""), "HTTP/1.1 403 Forbidden") << "no Host at all";
  EXPECT_EQ(server.requests_refused(), refused_before + 6);
  // A WebSocket under a rebound name, even from its own origin, and one without an Origin.
  const std::string rebound = "GET /live HTTP/1.1\r\nHost: evil.example:" + p +
                              "\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: "
                              "dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\nOrigin: http://evil.example:" +
                              p + "\r\n\r\n";
  EXPECT_NE(StatusLine(Exchange(port, rebound, false)), "HTTP/1.1 101 Switching Protocols");
  std::string without_origin = WebSocketRequest(port, "x");
  without_origin.erase(without_origin.find("Origin: x\r\n"), std::string("Origin: x\r\n").size());
  EXPECT_NE(StatusLine(Exchange(port, without_origin, false)), "HTTP/1.1 101 Switching Protocols");
  EXPECT_EQ(server.open_pages(), 0);
  // Names with a port or a slash are refused as settings.
  ViewerOptions wrong;
  wrong.allowed_hosts = "ground.local:8080";
  EXPECT_FALSE(wrong.Check(nullptr));
}

TEST(ViewerServer, AWebSocketOnlyFromThePagesOwnOriginAndOnlyAsManyAsAllowed) {
  ViewerState state(1000);
  ViewerOptions options;
  options.port = bus::UnusedTcpPort();
  options.max_pages = 2;
  ViewerServer server(options, &state);
  const int port = options.port;
  // Another site open in the same browser may not read the map.
  EXPECT_NE(StatusLine(Exchange(port, WebSocketRequest(port, "http://evil.example"), false)),
            "HTTP/1.1 101 Switching Protocols");
  // The page's own origin may: two sockets held open, a third refused.
  const auto open_socket = [&] {
    const int fd = testing::ConnectToLocalPort(port);
    EXPECT_GE(fd, 0);
    const std::string request = WebSocketRequest(port, "http://127.0.0.1:" + std::to_string(port));
    EXPECT_EQ(send(fd, request.data(), request.size(), MSG_NOSIGNAL), static_cast<ssize_t>(request.size()));
    // The reply may come in pieces (the handshake's blank line in one, the first frame in the next).
    std::string reply;
    char buffer[1024];
    for (int i = 0; i < 50 && reply.find("\r\n\r\n") == std::string::npos; ++i) {
      pollfd readable{fd, POLLIN, 0};
      if (poll(&readable, 1, 100) != 1) continue;
      const ssize_t n = recv(fd, buffer, sizeof(buffer), 0);
      if (n <= 0) break;
      reply.append(buffer, static_cast<size_t>(n));
    }
    return std::pair<int, std::string>{fd, reply};
  };
  const auto [first, first_reply] = open_socket();
  const auto [second, second_reply] = open_socket();
  EXPECT_EQ(StatusLine(first_reply), "HTTP/1.1 101 Switching Protocols");
  EXPECT_EQ(StatusLine(second_reply), "HTTP/1.1 101 Switching Protocols");
  for (int i = 0; i < 50 && server.open_pages() < 2; ++i) usleep(20000);
  EXPECT_EQ(server.open_pages(), 2);
  const auto [third, third_reply] = open_socket();
  EXPECT_NE(StatusLine(third_reply), "HTTP/1.1 101 Switching Protocols");
  // A page that opens is sent the state at once, before any push: its first frame is text (the
  // live state), final (0x81).
  const size_t handshake_end = first_reply.find("\r\n\r\n");
  std::string first_frame = handshake_end == std::string::npos ? "" : first_reply.substr(handshake_end + 4);
  if (first_frame.empty()) {
    pollfd readable{first, POLLIN, 0};
    char buffer[256];
    if (poll(&readable, 1, 5000) == 1) {
      const ssize_t n = recv(first, buffer, sizeof(buffer), 0);
      if (n > 0) first_frame.assign(buffer, static_cast<size_t>(n));
    }
  }
  ASSERT_FALSE(first_frame.empty()) << "nothing was sent to a page that opened";
  EXPECT_EQ(static_cast<unsigned char>(first_frame[0]), 0x81);
  // A push reaches both open pages.
  EXPECT_EQ(server.Push(0), 2);
  for (int fd : {first, second, third}) close(fd);
  for (int i = 0; i < 100 && server.open_pages() > 0; ++i) usleep(20000);
  EXPECT_EQ(server.open_pages(), 0);
}

// #45: a page that stops reading its WebSocket (or an attacker's socket that never reads) held
// every push, the other pages' too, until civetweb's write timed out, and kept its place among
// viewer.max_pages. Each page is now written to on its own: the pushes go on, the reading page
// gets every cloud, and a page that leaves a write unfinished for 10 s is closed.
TEST(ViewerServer, APageThatDoesNotReadHoldsUpOnlyItself) {
  ViewerState state(/*max_page_points=*/200000);
  std::string why;
  ASSERT_TRUE(state.OnGlobalMap(GlobalMap(), &why));
  ViewerOptions options;
  options.port = bus::UnusedTcpPort();
  options.max_pages = 3;
  ViewerServer server(options, &state);
  const int port = options.port;
  const auto open_page = [&](bool small_buffer) {
    const int fd = socket(AF_INET, SOCK_STREAM, 0);
    if (small_buffer) {
      const int bytes = 4096;
      setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &bytes, sizeof(bytes));
    }
    sockaddr_in to{};
    to.sin_family = AF_INET;
    to.sin_port = htons(static_cast<uint16_t>(port));
    to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    EXPECT_EQ(connect(fd, reinterpret_cast<const sockaddr*>(&to), sizeof(to)), 0);
    const std::string request = WebSocketRequest(port, "http://127.0.0.1:" + std::to_string(port));
    EXPECT_EQ(send(fd, request.data(), request.size(), MSG_NOSIGNAL), static_cast<ssize_t>(request.size()));
    return fd;
  };
  const int idle_first = open_page(true), idle_second = open_page(true);
  const int reader = open_page(false);
  for (int i = 0; i < 100 && server.open_pages() < 3; ++i) usleep(20000);
  ASSERT_EQ(server.open_pages(), 3);
  // The reading page takes everything it is sent and counts the binary frames' bytes (the clouds).
  std::atomic<bool> reading{true};
  std::atomic<int64_t> received{0};
  std::thread read([&] {
    char buffer[1 << 16];
    while (reading.load()) {
      pollfd readable{reader, POLLIN, 0};
      if (poll(&readable, 1, 50) != 1) continue;
      const ssize_t n = recv(reader, buffer, sizeof(buffer), 0);
      if (n <= 0) break;
      received += n;
    }
  });
  // Twenty clouds of 100,000 points (1.6 MB each on the socket): more than the idle pages' buffers.
  constexpr int kPushes = 20, kPoints = 100000;
  const Stopwatch clock;
  for (int revision = 1; revision <= kPushes; ++revision) {
    stitch::map_cloud_t cloud{};
    cloud.header.agent = "uav0";
    cloud.revision = revision;
    cloud.num_submaps = 1;
    cloud.submap_ids = {kFirst.value};
    cloud.components = {0};
    cloud.point_counts = {kPoints};
    for (int i = 0; i < kPoints; ++i) cloud.positions.insert(cloud.positions.end(), {float(i), float(revision), 1.f});
    cloud.num_coordinates = static_cast<int32_t>(cloud.positions.size());
    cloud.points_in_maps = kPoints;
    ASSERT_TRUE(state.OnMapCloud(cloud, &why)) << why;
    server.Push(revision);
    usleep(50000);
  }
  const double pushing_s = clock.ElapsedSeconds();
  // Blocked behind the idle pages, each push once waited out civetweb's write timeout (10 s).
  EXPECT_LT(pushing_s, 8.0) << "the pushes waited for pages that do not read";
  // The reading page got the last cloud: every push replaced what it had not taken yet, and the
  // last is sent once it has taken the one before.
  for (int i = 0; i < 200 && received.load() < int64_t{16} * kPoints; ++i) usleep(20000);
  EXPECT_GE(received.load(), int64_t{16} * kPoints);
  // The idle pages' writes time out (10 s): they give their places up, and a page opens where
  // all three were held.
  for (int i = 0; i < 300 && server.pages_given_up() < 2; ++i) usleep(100000);
  EXPECT_EQ(server.pages_given_up(), 2);
  EXPECT_EQ(server.open_pages(), 1);
  const int operator_page = open_page(false);
  for (int i = 0; i < 100 && server.open_pages() < 2; ++i) usleep(20000);
  EXPECT_EQ(server.open_pages(), 2) << "the operator's page is let in";
  reading = false;
  read.join();
  for (int fd : {idle_first, idle_second, reader, operator_page}) close(fd);
}

// #45: 230 slow connections (a request never finished) held civetweb's eight threads, and the
// operator's page did not load. Held connections are bounded, and a new one takes the place of
// the oldest that has not finished its request.
TEST(ViewerServer, SlowConnectionsDoNotLockTheOperatorOut) {
  ViewerState state(1000);
  ViewerOptions options;
  options.port = bus::UnusedTcpPort();
  ViewerServer server(options, &state);
  std::vector<int> slow;
  for (int i = 0; i < 300; ++i) {
    const int fd = testing::ConnectToLocalPort(options.port);
    if (fd < 0) continue;
    const std::string start = "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ";
    send(fd, start.data(), start.size(), MSG_NOSIGNAL);
    slow.push_back(fd);
  }
  EXPECT_GE(slow.size(), 290u);
  const Stopwatch clock;
  EXPECT_EQ(StatusLine(Exchange(options.port, "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")), "HTTP/1.1 200 OK");
  EXPECT_LT(clock.ElapsedSeconds(), 2.0);
  EXPECT_GE(server.connections_displaced(), static_cast<int64_t>(slow.size()) - ViewerServer::kMaxConnections);
  for (int fd : slow) close(fd);
}

// #45: civetweb read a WebSocket frame whole, up to 2 GB, before the viewer saw it: a page could
// make the viewer hold that much. A message larger than a page has reason to send (64 kB) ends
// its socket before it is read.
TEST(ViewerServer, AWebSocketMessageLargerThanAPageSendsClosesItsSocket) {
  ViewerState state(1000);
  ViewerOptions options;
  options.port = bus::UnusedTcpPort();
  ViewerServer server(options, &state);
  const int fd = testing::ConnectToLocalPort(options.port);
  ASSERT_GE(fd, 0);
  const std::string request = WebSocketRequest(options.port, "http://127.0.0.1:" + std::to_string(options.port));
  ASSERT_EQ(send(fd, request.data(), request.size(), MSG_NOSIGNAL), static_cast<ssize_t>(request.size()));
  for (int i = 0; i < 100 && server.open_pages() < 1; ++i) usleep(20000);
  ASSERT_EQ(server.open_pages(), 1);
  // A masked binary frame claiming 1 GB (64-bit length), then 32 MB of it (more than the
  // sockets' buffers hold).
  std::string frame = {static_cast<char>(0x82), static_cast<char>(0xFF)};
  for (int shift = 56; shift >= 0; shift -= 8) frame.push_back(static_cast<char>((uint64_t{1} << 30) >> shift));
  frame += std::string("\x12\x34\x56\x78", 4) + std::string(32 << 20, 'x');
  size_t sent = 0;
  while (sent < frame.size()) {
    const ssize_t n = send(fd, frame.data() + sent, frame.size() - sent, MSG_NOSIGNAL);
    if (n <= 0) break;  // the viewer closed the socket
    sent += static_cast<size_t>(n);
  }
  for (int i = 0; i < 100 && server.open_pages() > 0; ++i) usleep(20000);
  EXPECT_EQ(server.open_pages(), 0) << "the socket stayed open, " << sent << " bytes of 1 GB sent";
  EXPECT_LT(sent, frame.size()) << "the viewer read on past what a page may send";
  close(fd);
}

// #45: a viewer that others can reach needs its access token on every request: in the page's
// address (answered with a cookie that holds it), then in that cookie (the page's own requests and
// WebSocket); anything else is refused and counted.
TEST(ViewerServer, WithAnAccessTokenEveryRequestAndSocketMustCarryIt) {
  testing::TempDir dir;
  const std::string token_file = dir / "viewer.token";
  GenerateSecretFile(token_file, "viewer access token");
  const std::string token = SecretHex(LoadSecretFile(token_file, "viewer access token", ""));
  ViewerState state(1000);
  ViewerOptions options;
  options.port = bus::UnusedTcpPort();
  options.access_token_file = token_file;
  ViewerServer server(options, &state);
  const int port = options.port;
  EXPECT_EQ(server.url(), "http://127.0.0.1:" + std::to_string(port) + "/?token=" + token);
  const auto get = [&](const std::string& target, const std::string& more_headers = "") {
    return Exchange(port, "GET " + target + " HTTP/1.1\r\nHost: 127.0.0.1\r\n" + more_headers + "\r\n");
  };
  const int64_t refused_before = server.requests_refused();
  std::string wrong = token;
  wrong[10] = wrong[10] == 'a' ? 'b' : 'a';
  for (const std::string& target :
       std::vector<std::string>{"/", "/state.json", "/cloud.bin", "/?token=" + wrong, "/?token=" + token.substr(0, 63),
                                "/?token=", "/state.json?x=1&token=" + token + "0"}) {
    EXPECT_EQ(StatusLine(get(target)), "HTTP/1.1 401 Unauthorized") << target;
  }
  EXPECT_EQ(StatusLine(get("/", "Cookie: stitch_viewer_token=" + wrong + "\r\n")), "HTTP/1.1 401 Unauthorized");
  EXPECT_EQ(server.requests_refused(), refused_before + 8);
  // The page's address: served, with the cookie for what the page asks next.
  const std::string page = get("/?token=" + token);
  EXPECT_EQ(StatusLine(page), "HTTP/1.1 200 OK");
  EXPECT_NE(page.find("Set-Cookie: stitch_viewer_token=" + token + "; Path=/; HttpOnly; SameSite=Strict\r\n"),
            std::string::npos);
  EXPECT_NE(page.find("Referrer-Policy: no-referrer"), std::string::npos);
  EXPECT_EQ(StatusLine(get("/state.json?a=b&token=" + token)), "HTTP/1.1 200 OK");
  const std::string cookie = "Cookie: theme=dark; stitch_viewer_token=" + token + "\r\n";
  const std::string json = get("/state.json", cookie);
  EXPECT_EQ(StatusLine(json), "HTTP/1.1 200 OK");
  EXPECT_EQ(json.find("Set-Cookie"), std::string::npos) << "set once, from the address";
  // The WebSocket: refused without the cookie, even from the page's own origin; accepted with it.
  const std::string origin = "http://127.0.0.1:" + std::to_string(port);
  EXPECT_NE(StatusLine(Exchange(port, WebSocketRequest(port, origin), false)), "HTTP/1.1 101 Switching Protocols");
  std::string with_cookie = WebSocketRequest(port, origin);
  with_cookie.insert(with_cookie.size() - 2, cookie);
  EXPECT_EQ(StatusLine(Exchange(port, with_cookie, false)), "HTTP/1.1 101 Switching Protocols");
}

// Off loopback without a token file the server makes a token of its own, in the address it gives.
TEST(ViewerServer, OffLoopbackItMakesATokenOfItsOwn) {
  ViewerState state(1000);
  ViewerOptions options;
  options.port = bus::UnusedTcpPort();
  options.bind_address = "0.0.0.0";
  ViewerServer server(options, &state);
  const std::string prefix = "http://0.0.0.0:" + std::to_string(options.port) + "/?token=";
  ASSERT_EQ(server.url().rfind(prefix, 0), 0u) << server.url();
  const std::string token = server.url().substr(prefix.size());
  EXPECT_EQ(token.size(), 64u);
  EXPECT_EQ(token.find_first_not_of("0123456789abcdef"), std::string::npos);
  EXPECT_EQ(StatusLine(Exchange(options.port, "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")),
            "HTTP/1.1 401 Unauthorized");
  EXPECT_EQ(StatusLine(Exchange(options.port, "GET /?token=" + token + " HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")),
            "HTTP/1.1 200 OK");
  // A token file others may read is refused, with why.
  testing::TempDir dir;
  const std::string token_file = dir / "viewer.token";
  GenerateSecretFile(token_file, "viewer access token");
  std::filesystem::permissions(token_file, std::filesystem::perms::others_read, std::filesystem::perm_options::add);
  ViewerOptions leaked;
  leaked.port = bus::UnusedTcpPort();
  leaked.access_token_file = token_file;
  try {
    ViewerServer refused(leaked, &state);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("readable by others"), std::string::npos) << e.what();
  }
}

TEST(ViewerServer, WithoutThreeJsItSaysWhatToInstall) {
  ViewerState state(1000);
  ViewerOptions options;
  options.port = bus::UnusedTcpPort();
  options.three_dir = "/nonexistent/three";
  try {
    ViewerServer server(options, &state);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("libjs-three"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace stitch
