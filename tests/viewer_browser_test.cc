// The ground's live viewer end to end (issue #22): `stitch run --viewer` flies a strip with a gust
// on the real services, the viewer serves the page, and headless Chromium (Debian's chromium)
// loads it. Asserted from the page itself: the DOM after its scripts ran (submaps, keyframes,
// points, tracking state, an open WebSocket, no error) and a screenshot whose canvas is not blank;
// and from Chromium's log: no console error. Skipped where Chromium is not installed.

#include <signal.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>
#include <thread>

#include <gtest/gtest.h>
#include <Eigen/Geometry>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "services/common/bus.h"
#include "stitch/io/ply.h"
#include "stitch/io/trajectory.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/child_process.h"
#include "tests/test_process.h"

namespace stitch {
namespace {

using namespace std::chrono_literals;
using testing::Bin;

const char kChromium[] = "/usr/bin/chromium";

// <body data-*> of the page as Chromium left it: data-submaps -> "2", ...
std::map<std::string, std::string> BodyData(const std::string& dom) {
  std::map<std::string, std::string> data;
  std::smatch body;
  if (!std::regex_search(dom, body, std::regex("<body([^>]*)>"))) return data;
  const std::string attributes = body[1];
  const std::regex attribute("data-([a-z-]+)=\"([^\"]*)\"");
  for (auto it = std::sregex_iterator(attributes.begin(), attributes.end(), attribute); it != std::sregex_iterator();
       ++it) {
    data[(*it)[1]] = (*it)[2];
  }
  return data;
}

int Number(const std::map<std::string, std::string>& data, const std::string& key) {
  const auto it = data.find(key);
  return it == data.end() ? -1 : std::atoi(it->second.c_str());
}

// Chromium logs what the page writes on its console (errors, warnings, uncaught exceptions) as
// CONSOLE lines; the page writes nothing there when all is well (but for the GL driver's note
// that reading the pixels back, as the page's pixel count does, stalls).
std::string ConsoleLines(const std::string& output) {
  std::string console;
  std::istringstream lines(output);
  for (std::string line; std::getline(lines, line);) {
    if (line.find(":CONSOLE") != std::string::npos &&
        line.find("GL Driver Message (OpenGL, Performance") == std::string::npos) {
      console += line + "\n";
    }
  }
  return console;
}

std::vector<std::string> Chromium(const std::string& url, const std::vector<std::string>& more) {
  std::vector<std::string> args{kChromium,
                                "--headless",
                                "--no-sandbox",  // CI runs as root
                                "--disable-gpu",
                                "--enable-unsafe-swiftshader",
                                "--use-angle=swiftshader",
                                "--no-first-run",
                                "--window-size=1280,800",
                                "--virtual-time-budget=8000",
                                "--enable-logging=stderr",
                                "--v=0"};
  args.insert(args.end(), more.begin(), more.end());
  args.push_back(url);
  return args;
}

TEST(ViewerInBrowser, ThePageShowsTheFlightsSubmapsKeyframesPointsAndTrackingState) {
  if (access(kChromium, X_OK) != 0) {
    GTEST_SKIP() << "Chromium is not installed (Debian's chromium; .ci/run installs it): the viewer's page is not "
                    "loaded in a browser here";
  }
  stitch::testing::TempDir dir;
  const int port = bus::UnusedTcpPort();
  const std::string url = "http://127.0.0.1:" + std::to_string(port) + "/";
  const std::string log = dir / "run.log";
  // Chromium's first start reads its whole installation from disk: once before the flight, so the
  // page sampled during it loads while it goes on.
  testing::RunProgram(Chromium("about:blank", {"--dump-dom"}), 90);
  ChildProcess run("run", Bin("stitch"),
                   {"run", "--viewer", "--viewer-port", std::to_string(port), "--out", dir / "run", "--quiet", "--set",
                    "synthetic.flight.num_frames=200", "--set", "synthetic.flight.num_strips=1", "--set",
                    "synthetic.flight.strip_length_m=230", "--failures", "90:10", "--set",
                    // its live mosaic from the first pictures, as it is sampled during the flight
                    "merger.mosaic.live_min_pictures=3"},
                   log);
  const auto said = [&](const std::string& text) {
    std::ifstream in(log);
    const std::string all((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    return all.find(text) != std::string::npos;
  };
  // During the flight the page's state follows the tracker, and its mosaic view shows the tiles
  // the merger has laid so far (#43).
  int live_frame = -1;
  std::map<std::string, std::string> mosaic_during;
  const auto deadline = std::chrono::steady_clock::now() + 240s;
  while (!said("shows the finished flight")) {
    ASSERT_LT(std::chrono::steady_clock::now(), deadline) << run.LogTail(20);
    ASSERT_FALSE(run.Poll()) << run.LogTail(20);
    if (const auto state = testing::HttpGet(port, "/state.json"); state && live_frame < 0 && !said("outputs:")) {
      const nlohmann::json aircraft = nlohmann::json::parse(*state)["live"]["aircraft"];
      if (aircraft.contains("uav0") && aircraft["uav0"].contains("tracking")) {
        const int frame = aircraft["uav0"]["tracking"]["frame"].get<int>();
        if (frame > 0 && frame < 180) live_frame = frame;
      }
    }
    if (const auto state = testing::HttpGet(port, "/state.json"); state && mosaic_during.empty() && !said("outputs:")) {
      const nlohmann::json live = nlohmann::json::parse(*state)["live"];
      if (live.contains("mosaic") && !live["mosaic"]["tiles"].empty()) {
        const testing::CommandResult dom = testing::RunProgram(Chromium(url + "#mosaic", {"--dump-dom"}), 90);
        mosaic_during = BodyData(dom.output);
        mosaic_during["console"] = ConsoleLines(dom.output);
        // Chromium may take seconds to start: a page it loaded after the flight ended shows the
        // whole mosaic, not the flight's part of it.
        if (said("outputs:")) mosaic_during["after the flight"] = "yes";
      }
    }
    std::this_thread::sleep_for(100ms);
  }
  EXPECT_GT(live_frame, 0) << "the viewer's state never showed a frame while the flight went on";

  // The page after its scripts ran.
  const testing::CommandResult dom = testing::RunProgram(Chromium(url, {"--dump-dom"}), 90);
  ASSERT_EQ(dom.exit_code, 0) << dom.output.substr(0, 4000);
  const auto data = BodyData(dom.output);
  EXPECT_EQ(data.count("loaded"), 1u) << dom.output.substr(0, 4000);
  EXPECT_EQ(Number(data, "errors"), 0) << "errors on the page: " << dom.output.substr(0, 4000);
  EXPECT_EQ(data.count("ws") ? data.at("ws") : "", "open") << "the WebSocket did not open";
  EXPECT_GE(Number(data, "updates"), 1) << "nothing was pushed over the WebSocket";
  EXPECT_EQ(Number(data, "submaps"), 2) << "the gust's two submaps";
  EXPECT_GE(Number(data, "keyframes"), 30);
  EXPECT_GE(Number(data, "points"), 2000);
  EXPECT_EQ(data.count("tracking") ? data.at("tracking") : "", "OK");
  EXPECT_GE(Number(data, "drawn-pixels"), 2000) << "the canvas drew nothing";
  EXPECT_NE(dom.output.find("<td id=\"merged-count\">1</td>"), std::string::npos) << "the two submaps merged";
  EXPECT_EQ(ConsoleLines(dom.output), "");
  // #42: the flight's GNSS fixes place its map on Earth: the view shows north and a scale in
  // metres (a 230 m strip framed whole in 800 pixels: a bar of some metres to some tens of them).
  std::smatch scale;
  ASSERT_TRUE(std::regex_search(dom.output, scale, std::regex("id=\"scale-label\">([0-9.]+) (m|km|cm)<")))
      << "no scale on the page";
  EXPECT_EQ(dom.output.find("<div id=\"earth\" hidden"), std::string::npos) << "north and the scale are hidden";
  const double scale_metres = std::atof(data.count("scale-metres") ? data.at("scale-metres").c_str() : "-1");
  EXPECT_EQ(scale[2], "m");
  EXPECT_DOUBLE_EQ(std::atof(scale[1].str().c_str()), scale_metres);
  EXPECT_GE(scale_metres, 5.0);
  EXPECT_LE(scale_metres, 200.0);
  EXPECT_EQ(data.count("north-deg"), 1u) << "no north arrow";

  // The mosaic view: tiles during the flight, more once it ended, drawn, without a console line.
  const testing::CommandResult mosaic = testing::RunProgram(Chromium(url + "#mosaic", {"--dump-dom"}), 90);
  const auto mosaic_after = BodyData(mosaic.output);
  EXPECT_EQ(mosaic_after.count("view") ? mosaic_after.at("view") : "", "mosaic");
  EXPECT_GT(std::atof(mosaic_after.count("scale-metres") ? mosaic_after.at("scale-metres").c_str() : "-1"), 0.0)
      << "no scale over the mosaic";
  EXPECT_GE(Number(mosaic_during, "mosaic-tiles"), 1) << "no tile on the page during the flight";
  // The synthetic receiver's fixes place the maps: the mosaic is drawn where they put them.
  EXPECT_EQ(mosaic_after.count("mosaic-frame") ? mosaic_after.at("mosaic-frame") : "", "earth");
  if (!mosaic_during.count("after the flight")) {
    EXPECT_GT(Number(mosaic_after, "mosaic-tiles"), Number(mosaic_during, "mosaic-tiles"))
        << "the mosaic did not grow as the flight went on";
  } else {
    std::printf("the page sampled during the flight loaded after it ended: its growth is not measured\n");
  }
  EXPECT_GE(Number(mosaic_during, "mosaic-drawn-pixels"), 2000) << "the mosaic view drew nothing";
  // The view frames the whole mosaic, so a larger one may cover fewer of the canvas's pixels: the
  // growth is in the tiles' count above, the drawing only has to be there.
  EXPECT_GE(Number(mosaic_after, "mosaic-drawn-pixels"), 2000) << "the finished mosaic drew nothing";
  EXPECT_EQ(Number(mosaic_after, "errors"), 0) << mosaic.output.substr(0, 4000);
  EXPECT_EQ(mosaic_during.count("console") ? mosaic_during.at("console") : "?", "");
  EXPECT_EQ(ConsoleLines(mosaic.output), "");
  // From a picture's sending on the aircraft to its tile on the ground's viewer, the median (the
  // merger lays pictures every merger.mosaic.interval_s; a new submap's wait until it merges).
  const double latency =
      std::atof(mosaic_after.count("mosaic-latency") ? mosaic_after.at("mosaic-latency").c_str() : "-1");
  std::printf(
      "mosaic tiles on the page: %d during the flight, %d after; a picture's tile reached the viewer within %.2f s\n",
      Number(mosaic_during, "mosaic-tiles"), Number(mosaic_after, "mosaic-tiles"), latency);
  EXPECT_GE(latency, 0.0);
  EXPECT_LT(latency, 5.0);

  // A screenshot whose canvas (the page left of the 360-pixel panel) is not blank.
  const std::string shot = dir / "viewer.png";
  const testing::CommandResult screenshot = testing::RunProgram(Chromium(url, {"--screenshot=" + shot}), 90);
  ASSERT_EQ(screenshot.exit_code, 0) << screenshot.output.substr(0, 4000);
  const cv::Mat image = cv::imread(shot, cv::IMREAD_COLOR);
  ASSERT_FALSE(image.empty());
  int drawn = 0;
  for (int y = 40; y < image.rows; ++y) {
    for (int x = 0; x < std::min(image.cols, 1280 - 360); ++x) {
      const cv::Vec3b bgr = image.at<cv::Vec3b>(y, x);
      drawn += std::abs(bgr[2] - 16) + std::abs(bgr[1] - 20) + std::abs(bgr[0] - 26) > 40;
    }
  }
  EXPECT_GT(drawn, 2000) << "the canvas in " << shot << " is blank";

  EXPECT_EQ(run.Terminate(30000ms), 0) << run.LogTail(20);
}

// A handheld camera's real sequence (#46): on TUM fr1/rpy the page's "whole map" showed one dot,
// its view framing a point 2,390 units out that map.ply leaves out. The page frames the map as
// map.ply holds it (and the keyframes' path): its framed radius is that cloud's, not the raw one's.
TEST(ViewerInBrowser, ARealSequencesMapIsFramedAsMapPlyHoldsIt) {
  if (access(kChromium, X_OK) != 0) GTEST_SKIP() << "Chromium is not installed (Debian's chromium)";
  const std::string dataset = std::string(STITCH_DATASETS_DIR) + "/tum/rgbd_dataset_freiburg1_rpy";
  if (!std::filesystem::exists(dataset)) {
    GTEST_SKIP() << dataset << " is absent: real-data test skipped (datasets live in ../shared/datasets)";
  }
  stitch::testing::TempDir dir;
  const int port = bus::UnusedTcpPort();
  const std::string log = dir / "run.log";
  ChildProcess run("run", Bin("stitch"),
                   {"run", "--viewer", "--viewer-port", std::to_string(port), "--out", dir / "run", "--quiet",
                    "--dataset", dataset, "--failures", "none", "--max-frames", "300"},
                   log);
  const auto deadline = std::chrono::steady_clock::now() + 300s;
  while (true) {
    std::ifstream in(log);
    const std::string all((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (all.find("shows the finished flight") != std::string::npos) break;
    ASSERT_LT(std::chrono::steady_clock::now(), deadline) << run.LogTail(20);
    ASSERT_FALSE(run.Poll()) << run.LogTail(20);
    std::this_thread::sleep_for(200ms);
  }
  const testing::CommandResult dom =
      testing::RunProgram(Chromium("http://127.0.0.1:" + std::to_string(port) + "/", {"--dump-dom"}), 90);
  ASSERT_EQ(dom.exit_code, 0) << dom.output.substr(0, 4000);
  const auto data = BodyData(dom.output);
  EXPECT_EQ(Number(data, "errors"), 0) << dom.output.substr(0, 4000);
  ASSERT_EQ(data.count("framed-radius"), 1u) << "the view framed nothing: " << dom.output.substr(0, 4000);
  const double framed = std::stod(data.at("framed-radius"));
  // Half the diagonal of the box around a cloud's points (and the path's positions).
  const auto half_diagonal = [](const std::vector<ColouredPoint>& cloud, const Trajectory& path) {
    Eigen::AlignedBox3d box;
    for (const ColouredPoint& p : cloud) box.extend(p.position.cast<double>());
    for (const auto& pose : path.poses()) box.extend(pose.world_from_cam.translation);
    return std::max(1.0, box.diagonal().norm() / 2);  // the page frames at least a unit
  };
  const Trajectory path = Trajectory::ReadTum(dir / "run/trajectory.tum");
  const double exported = half_diagonal(ReadPly(dir / "run/map.ply"), path);
  const double raw = half_diagonal(ReadPly(dir / "run/map_raw.ply"), path);
  EXPECT_GT(framed, 0.5 * exported) << "map.ply's half diagonal " << exported << ", map_raw.ply's " << raw;
  EXPECT_LT(framed, 1.5 * exported) << "map.ply's half diagonal " << exported << ", map_raw.ply's " << raw;
  EXPECT_EQ(run.Terminate(30000ms), 0) << run.LogTail(20);
}

// Replays (issue #22): a flight recorded with `stitch record` and played back with lcm-logplayer
// onto another bus shows in stitch-viewer as it did live, with no other service running.
TEST(ViewerOnAReplay, ARecordedFlightPlayedBackShowsAsItWasFlown) {
  if (!testing::OnPath("lcm-logger")) GTEST_SKIP() << "lcm-logger not installed (Debian package liblcm-bin)";
  stitch::testing::TempDir dir;
  const std::vector<int> ports = bus::UnusedUdpPorts(2);
  const std::string url = bus::LocalUdpUrl(ports[0]), replay_url = bus::LocalUdpUrl(ports[1]);
  const std::string log = dir / "flight.lcmlog";
  {
    ChildProcess recorder("record", Bin("stitch"), {"record", "--lcm-url", url, log}, dir / "record.log");
    std::this_thread::sleep_for(1s);
    const testing::CommandResult flight =
        testing::RunProgram({Bin("stitch"), "run", "--lcm-url", url, "--out", dir / "run", "--quiet", "--set",
                             "synthetic.flight.num_frames=200", "--set", "synthetic.flight.num_strips=1", "--set",
                             "synthetic.flight.strip_length_m=230", "--failures", "90:10", "--set",
                             // its live mosaic from the first pictures, as it is sampled during the flight
                             "merger.mosaic.live_min_pictures=3"},
                            240);
    ASSERT_EQ(flight.exit_code, 0) << flight.output;
    std::this_thread::sleep_for(500ms);
    recorder.Terminate(5000ms);
  }
  const int port = bus::UnusedTcpPort();
  ChildProcess viewer("viewer", Bin("stitch-viewer"), {"--lcm-url", replay_url, "--port", std::to_string(port)},
                      dir / "viewer.log");
  for (int i = 0; i < 100 && !testing::HttpGet(port, "/state.json"); ++i) std::this_thread::sleep_for(50ms);
  const testing::CommandResult play =
      testing::RunProgram({"/usr/bin/lcm-logplayer", "--lcm-url=" + replay_url, "--speed=4", log}, 120);
  ASSERT_EQ(play.exit_code, 0) << play.output;
  std::this_thread::sleep_for(500ms);
  const std::optional<std::string> state = testing::HttpGet(port, "/state.json");
  ASSERT_TRUE(state) << viewer.LogTail(10);
  const nlohmann::json j = nlohmann::json::parse(*state);
  EXPECT_EQ(j["map"]["submaps"].size(), 2u) << *state;
  EXPECT_EQ(j["map"]["merged_maps"], 1);
  EXPECT_GE(j["map"]["keyframes"].get<int>(), 30);
  ASSERT_TRUE(j["live"]["aircraft"].contains("uav0")) << *state;
  EXPECT_EQ(j["live"]["aircraft"]["uav0"]["tracking"]["frame"], 199);
  EXPECT_EQ(j["live"]["aircraft"]["uav0"]["camera"]["component"], 0) << "the last frame in the merged map";
  EXPECT_EQ(j["live"]["refused"], 0);
  const std::optional<std::string> cloud = testing::HttpGet(port, "/cloud.bin");
  ASSERT_TRUE(cloud && cloud->size() >= 16);
  uint32_t header[4];
  std::memcpy(header, cloud->data(), sizeof(header));
  EXPECT_GT(header[2], 2000u) << "points of the replayed map cloud";
  EXPECT_EQ(viewer.Terminate(5000ms), 0) << viewer.LogTail(10);
}

// The process of `program` among the children of `parent` (0: none). Its name exactly (as the
// kernel keeps it, 15 characters): a child forked but not yet started is named as its parent
// ("stitch"), and killing it killed the merger.
pid_t ChildNamed(pid_t parent, const std::string& program) {
  for (const auto& entry : std::filesystem::directory_iterator("/proc")) {
    const std::string name = entry.path().filename().string();
    if (name.find_first_not_of("0123456789") != std::string::npos) continue;
    std::ifstream stat(entry.path() / "stat");
    std::string line;
    if (!std::getline(stat, line) || line.rfind(')') == std::string::npos) continue;
    const std::string comm = line.substr(line.find('(') + 1, line.rfind(')') - line.find('(') - 1);
    std::istringstream fields(line.substr(line.rfind(')') + 2));
    char state = 0;
    pid_t ppid = 0;
    if (fields >> state >> ppid && ppid == parent && state != 'Z' && comm == program.substr(0, 15)) {
      return std::stoi(name);
    }
  }
  return 0;
}

// The security issue's row: the viewer's death (a cut-off WebSocket frame crashed civetweb's
// thread) failed the flight ("the viewer exited unexpectedly"; 62 frames never reached the
// tracker). The viewer is a window on the flight: killed mid-flight it is started again, the
// flight goes on, and its figures are those of the same lockstep run without a viewer.
TEST(ViewerOnAFlight, AViewerKilledMidFlightIsStartedAgainAndCostsTheFlightNothing) {
  stitch::testing::TempDir dir;
  const std::vector<std::string> flight{"run",        "--config", testing::ShortFlightConfig(),
                                        "--failures", "none",     "--quiet"};
  const auto plain = testing::RunProgram(
      [&] {
        std::vector<std::string> args{Bin("stitch")};
        args.insert(args.end(), flight.begin(), flight.end());
        args.insert(args.end(), {"--out", dir / "plain"});
        return args;
      }(),
      180);
  ASSERT_EQ(plain.exit_code, 0) << plain.output;
  const int port = bus::UnusedTcpPort();
  std::vector<std::string> args = flight;
  args.insert(args.end(), {"--viewer", "--viewer-port", std::to_string(port), "--out", dir / "viewed"});
  ChildProcess run("run", Bin("stitch"), args, dir / "run.log");
  pid_t viewer = 0;
  for (int i = 0; i < 400 && !(viewer && testing::HttpGet(port, "/state.json")); ++i) {
    std::this_thread::sleep_for(25ms);
    if (!viewer) viewer = ChildNamed(run.pid(), "stitch-viewer");
  }
  ASSERT_NE(viewer, 0) << run.LogTail(20);
  ASSERT_EQ(kill(viewer, SIGKILL), 0);
  // Started again: a new viewer answers on the same port.
  pid_t again = 0;
  for (int i = 0; i < 400 && !(again && testing::HttpGet(port, "/state.json")); ++i) {
    std::this_thread::sleep_for(25ms);
    if (!again || again == viewer) again = ChildNamed(run.pid(), "stitch-viewer");
  }
  EXPECT_NE(again, 0) << run.LogTail(20);
  EXPECT_NE(again, viewer);
  // The flight ends as it would have; the launcher then keeps the viewer up until Ctrl-C.
  std::string log;
  for (int i = 0; i < 2400 && log.find("shows the finished flight") == std::string::npos && !run.Poll(); ++i) {
    std::this_thread::sleep_for(50ms);
    std::ifstream in(dir / "run.log");
    log.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  EXPECT_NE(log.find("the viewer exited unexpectedly (status 137"), std::string::npos) << log;
  EXPECT_NE(log.find("started again, the flight goes on"), std::string::npos) << log;
  kill(run.pid(), SIGINT);
  EXPECT_EQ(run.Terminate(10000ms), 0) << run.LogTail(20);
  const auto plain_report = testing::ReadJson(dir / "plain/report.json");
  const auto viewed_report = testing::ReadJson(dir / "viewed/report.json");
  for (const char* figure : {"frames_localized", "keyframes", "submaps", "submaps_merged", "ate_rmse_m"}) {
    EXPECT_EQ(viewed_report[figure], plain_report[figure]) << figure;
  }
  bool noted = false;
  const nlohmann::json run_info = testing::ReadJson(dir / "viewed/run.json");
  for (const auto& note : run_info["notes"])
    noted |= note.get<std::string>().find("viewer exited") != std::string::npos;
  EXPECT_TRUE(noted) << "run.json's notes say the viewer ended";
}

}  // namespace
}  // namespace stitch
