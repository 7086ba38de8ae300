// Speed of the synthetic flight: world generation and per-frame rendering (one core).
//   build/bin/synthetic_benchmark

#include <benchmark/benchmark.h>

#include "stitch/synthetic/synthetic_sequence.h"

namespace stitch {
namespace {

void BM_BuildWorld(benchmark::State& state) {
  for (auto _ : state) {
    SyntheticSequence sequence{SyntheticOptions{}, FailureSchedule{}};
    benchmark::DoNotOptimize(&sequence);
  }
}
BENCHMARK(BM_BuildWorld)->Unit(benchmark::kMillisecond)->Iterations(3);

void BM_RenderFrame(benchmark::State& state) {
  SyntheticOptions options;
  options.width = static_cast<int>(state.range(0));
  options.height = options.width * 3 / 4;
  options.focal_px = 450.0 * options.width / 640;
  SyntheticSequence sequence(options, FailureSchedule::DefaultGusts(options.flight.num_frames));
  int frame = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(sequence.RenderFrame(frame));
    frame = (frame + 7) % options.flight.num_frames;  // spread over the flight, gusts included
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_RenderFrame)->Arg(640)->Arg(752)->Arg(1280)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace stitch

BENCHMARK_MAIN();
