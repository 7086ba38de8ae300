// Reading a saved map (map_file.h) the size of a long survey's: N keyframes of 1,000 features,
// 600 of them on points, each point seen by 12 keyframes (a merged survey: 13). What `stitch run --map` and `stitch map
// info` pay before the flight.
//   build/bin/map_file_benchmark
// Counters: the file's size (MB) and keyframes read per second.

#include <random>

#include <benchmark/benchmark.h>

#include "stitch/map/map_file.h"

namespace stitch {
namespace {

std::string MapBytes(int keyframes) {
  const SubmapId id = MakeSubmapId(kSavedMapAgent, 0);
  const int features = 1000, observed = 600, views_per_point = 12;
  const int points = keyframes * observed / views_per_point;
  Map map(id, ScalePyramid::From(OrbOptions()));
  std::mt19937 rng(1);
  for (int j = 0; j < points; ++j) {
    MapPoint point;
    point.id = MakeMapPointId(id, static_cast<uint32_t>(j));
    point.position = Eigen::Vector3d(0.01 * j, std::uniform_real_distribution<double>(-20, 20)(rng), 70);
    for (uint8_t& b : point.descriptor) b = static_cast<uint8_t>(rng());
    point.normal = Eigen::Vector3d(0, 0, -1);
    point.min_distance = 50;
    point.max_distance = 90;
    map.AddPoint(point);
  }
  const Camera camera = Camera::Pinhole(1920, 1080, 1350, 1350, 960, 540);
  for (int k = 0; k < keyframes; ++k) {
    Keyframe keyframe;
    keyframe.id = MakeKeyframeId(id, static_cast<uint32_t>(k));
    keyframe.frame_index = 5 * k;
    keyframe.cam_from_world = Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(-0.01 * k * 100, 0, 0));
    keyframe.descriptors = cv::Mat(features, 32, CV_8U);
    cv::randu(keyframe.descriptors, 0, 256);
    keyframe.points.assign(features, MapPointId());
    for (int f = 0; f < features; ++f) {
      cv::KeyPoint kp(static_cast<float>(rng() % 1900), static_cast<float>(rng() % 1060), 31, (rng() % 360));
      kp.octave = static_cast<int>(rng() % 8);
      keyframe.keypoints.push_back(kp);
    }
    // Each band of views_per_point consecutive keyframes sees the same `observed` points.
    for (int i = 0; i < observed; ++i) {
      const int j = (k / views_per_point) * observed + i;
      if (j < points) keyframe.points[i] = MakeMapPointId(id, static_cast<uint32_t>(j));
    }
    map.AddKeyframe(std::move(keyframe));
  }
  const SavedMap saved = MakeSavedMap(
      map, [&](KeyframeId) { return &camera; }, "benchmark", id);
  return EncodeMapFile(saved);
}

void BM_ReadMapFile(benchmark::State& state) {
  const int keyframes = static_cast<int>(state.range(0));
  const std::string bytes = MapBytes(keyframes);
  for (auto _ : state) {
    const SavedMap read = DecodeMapFile(bytes, MakeSubmapId(kSavedMapAgent, 0));
    benchmark::DoNotOptimize(read.map.num_points());
  }
  state.counters["MB"] = static_cast<double>(bytes.size()) / 1e6;
  state.counters["keyframes_per_s"] = benchmark::Counter(keyframes, benchmark::Counter::kIsIterationInvariantRate);
}

BENCHMARK(BM_ReadMapFile)->Arg(200)->Arg(1000)->Arg(4000)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace stitch

BENCHMARK_MAIN();
