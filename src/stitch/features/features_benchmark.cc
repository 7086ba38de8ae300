// Speed of feature extraction, of the decoding and reduction of a large camera's frames before
// it, and of bag-of-words operations (one core; decoding: the decoder's threads counted too).
//   build/bin/features_benchmark [--benchmark_filter=...]
// Vocabulary benchmarks use vocabulary/default.stitchvoc when it exists.

#include <filesystem>
#include <map>

#include <benchmark/benchmark.h>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "stitch/features/keyframe_database.h"
#include "stitch/features/orb_extractor.h"
#include "stitch/features/vocabulary.h"
#include "stitch/io/video_decoder.h"
#include "stitch/io/video_file_writer.h"
#include "stitch/source/source.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

// A 640x480 frame of the synthetic flight, or a 752x480 EuRoC frame when the data is present.
cv::Mat Frame(bool euroc) {
  if (euroc) {
    const std::string path = std::string(STITCH_DATASETS_DIR) + "/euroc/V1_01_easy_micro";
    if (!std::filesystem::exists(path)) return {};
    auto sequence = OpenDataset(path);
    SequenceFrame frame;
    for (int i = 0; i < 40; ++i) sequence->Next(&frame);
    return frame.image;
  }
  SyntheticOptions options;
  options.flight.num_frames = 100;
  SyntheticSequence sequence(options, FailureSchedule());
  return sequence.RenderFrame(40);
}

void BM_StitchOrb(benchmark::State& state) {
  const cv::Mat image = Frame(state.range(0) == 1);
  if (image.empty()) return state.SkipWithError("EuRoC data absent");
  OrbExtractor extractor{OrbOptions{}};
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;
  for (auto _ : state) extractor.Extract(image, &keypoints, &descriptors);
  state.counters["features"] = static_cast<double>(keypoints.size());
}
BENCHMARK(BM_StitchOrb)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

void BM_OpenCvOrb(benchmark::State& state) {
  const cv::Mat image = Frame(state.range(0) == 1);
  if (image.empty()) return state.SkipWithError("EuRoC data absent");
  auto orb = cv::ORB::create(1000, 1.2f, 8, 19, 0, 2, cv::ORB::HARRIS_SCORE, 31, 20);
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;
  for (auto _ : state) orb->detectAndCompute(image, cv::noArray(), keypoints, descriptors);
  state.counters["features"] = static_cast<double>(keypoints.size());
}
BENCHMARK(BM_OpenCvOrb)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// A 1080p (range 0: 1080) or 4K (2160) frame reduced to its working size within range 1 pixels
// (ingest.max_working_pixels): 500,000 gives 942x530, halvings then a fractional step; 518,400
// (the default) gives 960x540, halvings alone. BM_ReduceInOneStep: one fractional area
// reduction from the full frame, for comparison.
template <bool kInOneStep>
void Reduce(benchmark::State& state) {
  const int height = static_cast<int>(state.range(0)), width = height * 16 / 9;
  cv::Mat frame;
  cv::resize(Frame(false), frame, cv::Size(width, height), 0, 0, cv::INTER_LINEAR);
  const auto [w, h] = WorkingSize(width, height, static_cast<int>(state.range(1)));
  // On one thread: OpenCV would spread a reduction over its own threads, whose CPU time the
  // benchmark's does not count.
  const int threads = cv::getNumThreads();
  cv::setNumThreads(0);
  cv::Mat reduced;
  for (auto _ : state) {
    if (kInOneStep) {
      cv::resize(frame, reduced, cv::Size(w, h), 0, 0, cv::INTER_AREA);
    } else {
      reduced = ReduceToWorkingSize(frame, cv::Size(w, h));
    }
    benchmark::DoNotOptimize(reduced.data);
  }
  cv::setNumThreads(threads);
  state.counters["width"] = w;
}
void BM_ReduceToWorkingSize(benchmark::State& state) {
  Reduce<false>(state);
}
void BM_ReduceInOneStep(benchmark::State& state) {
  Reduce<true>(state);
}
BENCHMARK(BM_ReduceToWorkingSize)
    ->Args({1080, 500000})
    ->Args({1080, 518400})
    ->Args({2160, 500000})
    ->Args({2160, 518400})
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ReduceInOneStep)->Args({1080, 500000})->Args({2160, 500000})->Unit(benchmark::kMillisecond);

// An H.264 clip of 60 frames of 1080p (range 0: 1080) or 4K (2160), the synthetic frame moving
// across it, decoded to grey: range 1 = 0 through OpenCV's reader (BGR, then grey), 1 through
// VideoDecoder (the luma plane). Per frame, the CPU of every thread of the process.
const std::string& H264Clip(int height) {
  static const std::filesystem::path folder = [] {
    const std::filesystem::path dir = std::filesystem::temp_directory_path() / "stitch-features-benchmark";
    std::filesystem::create_directories(dir);
    return dir;
  }();
  static std::map<int, std::string> clips;
  std::string& clip = clips[height];
  if (!clip.empty()) return clip;
  const int width = height * 16 / 9;
  cv::Mat image;
  cv::resize(Frame(false), image, cv::Size(width + 120, height), 0, 0, cv::INTER_LINEAR);
  clip = (folder / ("clip-" + std::to_string(height) + ".mp4")).string();
  H264FileWriter writer(clip, width, height);
  for (int i = 0; i < 60; ++i) writer.Write(image(cv::Rect(2 * i, 0, width, height)).clone());
  writer.Finish();
  return clip;
}

void BM_DecodeH264ToGray(benchmark::State& state) {
  std::string clip;
  try {
    clip = H264Clip(static_cast<int>(state.range(0)));
  } catch (const std::exception& e) {
    return state.SkipWithError(e.what());  // no x264 encoder (gstreamer1.0-plugins-ugly)
  }
  const bool decoder = state.range(1) == 1;
  int64_t frames = 0;
  for (auto _ : state) {
    cv::Mat gray, bgr;
    int64_t t_ns = 0;
    if (decoder) {
      VideoDecoder video(clip);
      while (video.Read(&gray, &t_ns)) ++frames;
    } else {
      cv::VideoCapture video(clip, cv::CAP_FFMPEG);
      while (video.read(bgr)) {
        cv::cvtColor(bgr, gray, cv::COLOR_BGR2GRAY);
        ++frames;
      }
    }
    benchmark::DoNotOptimize(gray.data);
  }
  state.counters["frames"] = static_cast<double>(frames);
  state.counters["s_per_frame"] =
      benchmark::Counter(static_cast<double>(frames), benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_DecodeH264ToGray)
    ->Args({1080, 0})
    ->Args({1080, 1})
    ->Args({2160, 0})
    ->Args({2160, 1})
    ->MeasureProcessCPUTime()
    ->Unit(benchmark::kMillisecond);

const Vocabulary* DefaultVocabulary() {
  static const Vocabulary* vocabulary = [] {
    const std::string path = std::string(STITCH_SOURCE_DIR) + "/vocabulary/default.stitchvoc";
    return std::filesystem::exists(path) ? new Vocabulary(Vocabulary::Load(path)) : nullptr;
  }();
  return vocabulary;
}

void BM_VocabularyLoad(benchmark::State& state) {
  const std::string path = std::string(STITCH_SOURCE_DIR) + "/vocabulary/default.stitchvoc";
  if (!std::filesystem::exists(path)) return state.SkipWithError("no vocabulary/default.stitchvoc");
  for (auto _ : state) benchmark::DoNotOptimize(Vocabulary::Load(path));
}
BENCHMARK(BM_VocabularyLoad)->Unit(benchmark::kMillisecond);

void BM_TransformKeyframe(benchmark::State& state) {
  const Vocabulary* vocabulary = DefaultVocabulary();
  if (!vocabulary) return state.SkipWithError("no vocabulary/default.stitchvoc");
  OrbExtractor extractor{OrbOptions{}};
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;
  extractor.Extract(Frame(false), &keypoints, &descriptors);
  FeatureVector features;
  for (auto _ : state) benchmark::DoNotOptimize(vocabulary->Transform(descriptors, &features));
  state.counters["features"] = descriptors.rows;
}
BENCHMARK(BM_TransformKeyframe)->Unit(benchmark::kMicrosecond);

void BM_DatabaseQuery(benchmark::State& state) {
  const Vocabulary* vocabulary = DefaultVocabulary();
  if (!vocabulary) return state.SkipWithError("no vocabulary/default.stitchvoc");
  // Keyframes with 1000 random descriptors each: a worst case for the inverted index, since
  // random descriptors spread over all words.
  Rng rng(5);
  KeyframeDatabase database;
  cv::Mat descriptors(1000, 32, CV_8U);
  BowVector query;
  for (int k = 0; k < state.range(0); ++k) {
    for (int i = 0; i < descriptors.rows; ++i) {
      for (int b = 0; b < 32; ++b) descriptors.at<uint8_t>(i, b) = static_cast<uint8_t>(rng.NextU64());
    }
    const BowVector bow = vocabulary->Transform(descriptors);
    database.Add(k, k % 10, bow);
    if (k == 0) query = bow;
  }
  for (auto _ : state) benchmark::DoNotOptimize(database.Query(query, [](int64_t submap) { return submap != 3; }));
}
BENCHMARK(BM_DatabaseQuery)->Arg(1000)->Arg(10000)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace stitch

BENCHMARK_MAIN();
