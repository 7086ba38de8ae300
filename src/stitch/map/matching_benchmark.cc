// Matching a reference keyframe's points to a frame without a pose (reference-keyframe tracking,
// relocalization): the vocabulary's direct index, brute force, our LSH index, and OpenCV's FLANN
// LSH for comparison. Rendered frames with true depth and poses, so every match is checked.
//   build/bin/matching_benchmark
// Counters: matches found, inliers (within 3 px of where the true pose projects the point),
// inlier ratio, and matches per second. LSH arguments: tables, key bits, probing one bit away
// (0 0 0: the defaults).

#include <benchmark/benchmark.h>
#include <opencv2/features2d.hpp>

#include "stitch/features/vocabulary.h"
#include "stitch/map/matcher.h"
#include "stitch/testing/rendered_views.h"

namespace stitch {
namespace {

enum Method { kBow, kBruteForce, kLsh, kFlannLsh };

struct Setup {
  testing::RenderedViews views;
  Vocabulary vocabulary = Vocabulary::Load(std::string(STITCH_SOURCE_DIR) + "/vocabulary/default.stitchvoc");
  Frame reference;
  Keyframe keyframe;
  Map map{MakeSubmapId(0, 1), ScalePyramid::From(OrbOptions())};
  Frame current;
  Setup() {
    cv::Mat depth;
    reference = views.Render(77, &depth);
    reference.bow = vocabulary.Transform(reference.descriptors, &reference.bow_features, 2);
    map = views.MapFromFrame(reference, depth, &keyframe);
    current = views.Render(85);
    current.bow = vocabulary.Transform(current.descriptors, &current.bow_features, 2);
  }
};

Setup& Shared() {
  static Setup* setup = new Setup();
  return *setup;
}

// OpenCV's FLANN LSH (12 tables, 20-bit keys, multi-probe 2: its documented ORB settings) with
// the same acceptance as ours: best under 50 bits, ratio 0.7 to the second.
int SearchByFlannLsh(const Keyframe& keyframe, Frame* frame, const Map& map) {
  cv::FlannBasedMatcher matcher(cv::makePtr<cv::flann::LshIndexParams>(12, 20, 2));
  cv::Mat query;
  std::vector<int> rows;
  for (size_t i = 0; i < keyframe.points.size(); ++i) {
    if (!keyframe.points[i].valid() || !map.FindPoint(keyframe.points[i])) continue;
    query.push_back(keyframe.descriptors.row(static_cast<int>(i)));
    rows.push_back(static_cast<int>(i));
  }
  std::vector<std::vector<cv::DMatch>> knn;
  matcher.knnMatch(query, frame->descriptors, knn, 2);
  int matched = 0;
  for (const auto& pair : knn) {
    if (pair.empty() || pair[0].distance > kDescriptorDistanceLow) continue;
    if (pair.size() > 1 && pair[0].distance >= 0.7 * pair[1].distance) continue;
    if (frame->points[pair[0].trainIdx].valid()) continue;
    frame->points[pair[0].trainIdx] = keyframe.points[rows[pair[0].queryIdx]];
    ++matched;
  }
  return matched;
}

void BM_MatchReferenceKeyframe(benchmark::State& state) {
  Setup& s = Shared();
  const Method method = static_cast<Method>(state.range(0));
  Frame frame = s.current;
  int matched = 0;
  for (auto _ : state) {
    std::fill(frame.points.begin(), frame.points.end(), MapPointId());
    switch (method) {
      case kBow:
        matched = SearchByBow(s.keyframe, &frame, s.map);
        break;
      case kBruteForce:
        matched =
            SearchByIndex(s.keyframe, &frame, s.map, DescriptorIndex(frame.descriptors, DescriptorSearch::kBruteForce));
        break;
      case kLsh: {
        LshOptions lsh;
        if (state.range(1) > 0) {
          lsh.tables = static_cast<int>(state.range(1));
          lsh.key_bits = static_cast<int>(state.range(2));
          lsh.probe_neighbours = state.range(3) != 0;
        }
        matched =
            SearchByIndex(s.keyframe, &frame, s.map, DescriptorIndex(frame.descriptors, DescriptorSearch::kLsh, lsh));
        break;
      }
      case kFlannLsh:
        matched = SearchByFlannLsh(s.keyframe, &frame, s.map);
        break;
    }
  }
  int count = 0;
  const double ratio = s.views.Consistency(frame, s.map, 3.0, &count);
  state.SetLabel(method == kBow          ? "bow"
                 : method == kBruteForce ? "brute force"
                 : method == kLsh        ? "lsh"
                                         : "opencv flann lsh");
  state.counters["matches"] = matched;
  state.counters["inliers"] = ratio * count;
  state.counters["inlier_ratio"] = ratio;
  state.counters["matches_per_s"] =
      benchmark::Counter(static_cast<double>(matched), benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_MatchReferenceKeyframe)
    ->Args({kBow, 0, 0, 0})
    ->Args({kBruteForce, 0, 0, 0})
    ->Args({kLsh, 0, 0, 0})
    ->Args({kLsh, 8, 8, 0})
    ->Args({kLsh, 16, 12, 0})
    ->Args({kLsh, 6, 10, 1})
    ->Args({kFlannLsh, 0, 0, 0})
    ->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace stitch

BENCHMARK_MAIN();
