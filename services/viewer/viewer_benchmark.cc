// What a push costs the viewer's server for a large map: the points made into the page's binary
// cloud (thinned to viewer.max_page_points) and the map update's JSON. And the page's own frame
// rate holding that many points (BM_PageFrameRate): the page loaded in headless Chromium, asked
// over the DevTools protocol after 10 s of drawing; in software (SwiftShader) unless
// STITCH_CHROMIUM_GPU=1 lets Chromium use the machine's GPU.
//   build/bin/viewer_benchmark
// Counters: points in the map, bytes sent to a page; the page's frames per second.

#include <unistd.h>

#include <chrono>
#include <condition_variable>
#include <cstdlib>
#include <mutex>
#include <random>
#include <thread>

#include <sys/socket.h>
#include <sys/time.h>

#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/websocket.hpp>
#include <nlohmann/json.hpp>

#include <benchmark/benchmark.h>

#include "services/common/convert.h"
#include "services/viewer/viewer_server.h"
#include "services/viewer/viewer_state.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/child_process.h"
#include "stitch/util/error.h"
#include "stitch/util/ids.h"
#include "tests/test_process.h"

namespace stitch {
namespace {

// A map of `submaps` submaps of `points` points each and `keyframes` keyframes each.
void Feed(ViewerState* state, int submaps, int points, int keyframes) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> coordinate(-100.f, 100.f);
  stitch::global_map_t map{};
  map.header.agent = "uav0";
  map.revision = 1;
  stitch::map_cloud_t cloud{};
  cloud.header.agent = "uav0";
  cloud.revision = 1;
  for (int s = 0; s < submaps; ++s) {
    const SubmapId id = MakeSubmapId(0, s + 1);
    stitch::submap_placement_t p{};
    p.agent = "uav0";
    p.submap_id = id.value;
    p.component = 0;
    p.world_from_submap = ToMessage(Sim3d());
    p.num_keyframes = keyframes;
    p.num_points = points;
    map.submaps.push_back(p);
    for (int k = 0; k < keyframes; ++k) {
      stitch::trajectory_pose_t t{};
      t.frame_index = k;
      t.submap_id = id.value;
      t.world_from_cam = ToMessage(Sim3d(1.0, Eigen::Quaterniond::Identity(), Eigen::Vector3d(k, s, 0)));
      map.trajectory.push_back(t);
    }
    cloud.submap_ids.push_back(id.value);
    cloud.components.push_back(0);
    cloud.point_counts.push_back(points);
    for (int i = 0; i < 3 * points; ++i) cloud.positions.push_back(coordinate(rng));
  }
  map.num_submaps = submaps;
  map.num_poses = static_cast<int32_t>(map.trajectory.size());
  cloud.num_submaps = submaps;
  cloud.num_coordinates = static_cast<int32_t>(cloud.positions.size());
  std::string why;
  if (!state->OnGlobalMap(map, &why) || !state->OnMapCloud(cloud, &why)) throw Error(why);
}

void BM_CloudForThePage(benchmark::State& bench) {
  const int points = static_cast<int>(bench.range(0));
  ViewerState state(/*max_page_points=*/500000);
  Feed(&state, 10, points / 10, 100);
  size_t bytes = 0;
  for (auto _ : bench) {
    const std::string cloud = state.CloudBinary();
    bytes = cloud.size();
    benchmark::DoNotOptimize(cloud.data());
  }
  bench.counters["points"] = points;
  bench.counters["bytes"] = static_cast<double>(bytes);
}
BENCHMARK(BM_CloudForThePage)->Arg(100000)->Arg(500000)->Arg(2000000)->Unit(benchmark::kMillisecond);

void BM_MapUpdate(benchmark::State& bench) {
  const int keyframes = static_cast<int>(bench.range(0));
  ViewerState state(500000);
  Feed(&state, 10, 1000, keyframes / 10);
  size_t bytes = 0;
  for (auto _ : bench) {
    const std::string json = state.MapJson();
    bytes = json.size();
    benchmark::DoNotOptimize(json.data());
  }
  bench.counters["keyframes"] = keyframes;
  bench.counters["bytes"] = static_cast<double>(bytes);
}
BENCHMARK(BM_MapUpdate)->Arg(250)->Arg(5000)->Unit(benchmark::kMillisecond);

// One DevTools request over a WebSocket (Boost.Beast's client) and its reply.
class DevToolsPage {
 public:
  DevToolsPage(int port, const std::string& path) {
    namespace net = boost::asio;
    socket_.next_layer().connect({net::ip::make_address("127.0.0.1"), static_cast<uint16_t>(port)});
    const timeval ten_seconds{10, 0};  // a read waits at most this long (then throws)
    setsockopt(socket_.next_layer().native_handle(), SOL_SOCKET, SO_RCVTIMEO, &ten_seconds, sizeof(ten_seconds));
    socket_.handshake("127.0.0.1:" + std::to_string(port), path);
  }
  std::string Evaluate(const std::string& expression) {
    const std::string request = nlohmann::json{{"id", 1},
                                               {"method", "Runtime.evaluate"},
                                               {"params", {{"expression", expression}, {"returnByValue", true}}}}
                                    .dump();
    socket_.text(true);
    socket_.write(boost::asio::buffer(request));
    for (;;) {
      boost::beast::flat_buffer buffer;
      socket_.read(buffer);
      const std::string text = boost::beast::buffers_to_string(buffer.data());
      if (text.find("\"id\":1") == std::string::npos) continue;  // an event, not the reply
      return nlohmann::json::parse(text)["result"]["result"]["value"].get<std::string>();
    }
  }

 private:
  boost::asio::io_context io_;
  boost::beast::websocket::stream<boost::asio::ip::tcp::socket> socket_{io_};
};

void BM_PageFrameRate(benchmark::State& bench) {
  const char* chromium = "/usr/bin/chromium";
  if (access(chromium, X_OK) != 0) {
    bench.SkipWithError("Chromium is not installed (Debian's chromium)");
    return;
  }
  const int points = static_cast<int>(bench.range(0));
  ViewerState state(/*max_page_points=*/points);
  Feed(&state, 10, points / 10, 100);
  ViewerOptions options;
  options.port = 18500 + getpid() % 400;
  ViewerServer server(options, &state);
  const int devtools = options.port + 400;
  nlohmann::json dataset;
  for (auto _ : bench) {
    testing::TempDir profile;
    std::vector<std::string> args{"--headless",
                                  "--no-sandbox",
                                  "--no-first-run",
                                  "--window-size=1280,800",
                                  "--remote-debugging-port=" + std::to_string(devtools),
                                  "--remote-allow-origins=*",
                                  "--user-data-dir=" + profile.path().string()};
    if (!std::getenv("STITCH_CHROMIUM_GPU")) {
      args.insert(args.end(), {"--disable-gpu", "--enable-unsafe-swiftshader", "--use-angle=swiftshader"});
    }
    args.push_back(server.url());
    ChildProcess browser("chromium", chromium, args, profile / "chromium.log");
    std::string path;
    for (int i = 0; i < 100 && path.empty(); ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
      const std::optional<std::string> pages = testing::HttpGet(devtools, "/json");
      if (!pages) continue;
      for (const auto& page : nlohmann::json::parse(*pages)) {
        if (page["type"] == "page" && page["url"].get<std::string>().rfind(server.url(), 0) == 0) {
          const std::string url = page["webSocketDebuggerUrl"].get<std::string>();
          path = url.substr(url.find('/', std::string("ws://").size()));
        }
      }
    }
    if (path.empty()) {
      bench.SkipWithError("Chromium's DevTools did not list the page");
      return;
    }
    std::this_thread::sleep_for(std::chrono::seconds(10));  // loaded, then drawing
    DevToolsPage page(devtools, path);
    dataset = nlohmann::json::parse(page.Evaluate("JSON.stringify(document.body.dataset)"));
    browser.Terminate(std::chrono::milliseconds(5000));
  }
  bench.counters["points_shown"] = std::atof(dataset.value("points", "0").c_str());
  bench.counters["view_fps"] = std::atof(dataset.value("viewFps", "0").c_str());
}
BENCHMARK(BM_PageFrameRate)->Arg(100000)->Arg(500000)->Iterations(1)->Unit(benchmark::kSecond);

}  // namespace
}  // namespace stitch
BENCHMARK_MAIN();
