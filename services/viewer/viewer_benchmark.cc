// What a push costs the viewer's server for a large map: the points made into the page's binary
// cloud (thinned to viewer.max_page_points) and the map update's JSON.
//   build/bin/viewer_benchmark
// Counters: points in the map, bytes sent to a page.

#include <random>

#include <benchmark/benchmark.h>

#include "services/common/convert.h"
#include "services/viewer/viewer_state.h"
#include "stitch/util/error.h"
#include "stitch/util/ids.h"

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

}  // namespace
}  // namespace stitch
BENCHMARK_MAIN();
