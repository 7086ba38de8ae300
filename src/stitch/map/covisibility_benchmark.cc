// Keeping the covisibility graph: Map::UpdateConnections over every keyframe of a local map the
// size of TUM fr1/rpy's (60 keyframes of 1,000 features, 600 on points, each point seen by the 10
// keyframes around its own). The tracker does this for each keyframe the mapper changed, on
// every local map update it applies; the mapper for each keyframe it adds.
//   build/bin/covisibility_benchmark
// Counter: keyframes connected per second.

#include <benchmark/benchmark.h>

#include "stitch/map/map.h"

namespace stitch {
namespace {

void BM_UpdateConnections(benchmark::State& state) {
  const SubmapId id = MakeSubmapId(0, 1);
  const int keyframes = static_cast<int>(state.range(0)), features = 1000, observed = 600, views_per_point = 10;
  Map map(id, ScalePyramid::From(OrbOptions()));
  for (int k = 0; k < keyframes; ++k) {
    Keyframe keyframe;
    keyframe.id = MakeKeyframeId(id, static_cast<uint32_t>(k));
    keyframe.frame_index = 10 * k;
    keyframe.keypoints.resize(features);
    keyframe.points.assign(features, MapPointId());
    map.AddKeyframe(std::move(keyframe));
  }
  // Point j is first seen by keyframe j / (observed / views_per_point) and the views_per_point - 1
  // after it: each keyframe sees `observed` points, a tenth of them new.
  const int new_per_keyframe = observed / views_per_point;
  for (int j = 0; j < keyframes * new_per_keyframe; ++j) {
    MapPoint point;
    point.id = MakeMapPointId(id, static_cast<uint32_t>(j));
    point.position = Eigen::Vector3d(0.01 * j, 0, 2);
    map.AddPoint(point);
    const int first = j / new_per_keyframe;
    for (int k = first; k < first + views_per_point && k < keyframes; ++k) {
      map.AddObservation(MakeKeyframeId(id, static_cast<uint32_t>(k)), (j + k) % features, point.id);
    }
  }
  map.ConnectAll();
  for (auto _ : state) {
    for (int k = 0; k < keyframes; ++k) map.UpdateConnections(MakeKeyframeId(id, static_cast<uint32_t>(k)));
  }
  state.counters["keyframes/s"] =
      benchmark::Counter(static_cast<double>(state.iterations()) * keyframes, benchmark::Counter::kIsRate);
}
BENCHMARK(BM_UpdateConnections)->Arg(60)->Arg(300)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace stitch

BENCHMARK_MAIN();
