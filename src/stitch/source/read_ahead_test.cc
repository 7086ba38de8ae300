#include "stitch/source/read_ahead.h"

#include <atomic>
#include <chrono>
#include <thread>

#include <gtest/gtest.h>

#include "stitch/source/source.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

using namespace std::chrono_literals;

// Small frames, counted as they are read; endless unless `length` is set; Next() throws for the
// frame `throws_at`; live when told.
class CountingSequence : public ImageSequence {
 public:
  explicit CountingSequence(std::atomic<int>* reads, int length = -1, int throws_at = -1, bool live = false)
      : reads_(reads), length_(length), throws_at_(throws_at), live_(live) {}
  std::string description() const override { return "counting"; }
  int size() const override { return length_; }
  const Camera& camera() const override { return camera_; }
  double nominal_fps() const override { return 30; }
  const Trajectory& ground_truth() const override { return ground_truth_; }
  bool live() const override { return live_; }
  bool Next(SequenceFrame* frame) override {
    if (next_ == length_) return false;
    if (next_ == throws_at_) throw Error("frame " + std::to_string(next_) + " is damaged");
    ++*reads_;
    frame->index = next_;
    frame->t_ns = next_ * 1'000'000LL;
    frame->image = cv::Mat(4, 4, CV_8UC1, cv::Scalar(next_ % 256));
    ++next_;
    return true;
  }

 private:
  std::atomic<int>* reads_;
  int length_, throws_at_;
  bool live_;
  int next_ = 0;
  Camera camera_ = Camera::Pinhole(4, 4, 4, 4, 2, 2);
  Trajectory ground_truth_;
};

bool WaitFor(const std::function<bool()>& done) {
  const auto deadline = std::chrono::steady_clock::now() + 10s;
  while (!done()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(1ms);
  }
  return true;
}

TEST(ReadAhead, PlaysTheSourcesFramesInOrderAndSaysWhatItSays) {
  SourceSpec spec;
  spec.synthetic.flight.num_frames = 6;
  FailureSchedule spoil;
  auto direct = OpenSource(spec, &spoil);
  auto ahead = ReadAhead(OpenSource(spec, &spoil), 2);
  EXPECT_EQ(ahead->description(), direct->description());
  EXPECT_EQ(ahead->size(), 6);
  EXPECT_EQ(ahead->camera().width(), direct->camera().width());
  EXPECT_EQ(ahead->nominal_fps(), direct->nominal_fps());
  EXPECT_EQ(ahead->ground_truth().size(), direct->ground_truth().size());
  SequenceFrame a, b;
  int frames = 0;
  while (direct->Next(&a)) {
    ASSERT_TRUE(ahead->Next(&b)) << "frame " << a.index;
    EXPECT_EQ(b.index, a.index);
    EXPECT_EQ(b.t_ns, a.t_ns);
    EXPECT_EQ(cv::norm(a.image, b.image, cv::NORM_INF), 0) << "frame " << a.index;
    ++frames;
  }
  EXPECT_EQ(frames, 6);
  EXPECT_FALSE(ahead->Next(&b));
  EXPECT_FALSE(ahead->Next(&b)) << "and stays ended";
}

TEST(ReadAhead, ReadsNoMoreThanItsFramesAhead) {
  std::atomic<int> reads{0};
  auto ahead = ReadAhead(std::make_unique<CountingSequence>(&reads), 3);
  ASSERT_TRUE(WaitFor([&] { return reads.load() == 3; }));
  std::this_thread::sleep_for(50ms);
  EXPECT_EQ(reads.load(), 3) << "an endless source is read 3 frames ahead, no more";
  SequenceFrame frame;
  ASSERT_TRUE(ahead->Next(&frame));
  EXPECT_EQ(frame.index, 0);
  EXPECT_TRUE(WaitFor([&] { return reads.load() == 4; })) << "a frame taken makes room for the next";
  // Destroyed while its reader waits for room: it stops.
}

TEST(ReadAhead, ASourcesErrorComesAfterTheFramesBeforeIt) {
  std::atomic<int> reads{0};
  auto ahead = ReadAhead(std::make_unique<CountingSequence>(&reads, -1, 2), 8);
  SequenceFrame frame;
  ASSERT_TRUE(ahead->Next(&frame));
  ASSERT_TRUE(ahead->Next(&frame));
  EXPECT_EQ(frame.index, 1);
  try {
    ahead->Next(&frame);
    FAIL() << "the damaged frame's error was not thrown";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("frame 2 is damaged"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(ahead->Next(&frame)) << "nothing after it";
}

TEST(ReadAhead, ALiveSourceOrNoFramesLeavesTheSourceAsItIs) {
  std::atomic<int> reads{0};
  auto live = std::make_unique<CountingSequence>(&reads, 5, -1, true);
  const ImageSequence* source = live.get();
  EXPECT_EQ(ReadAhead(std::move(live), 8).get(), source) << "a live camera keeps its newest frame itself";
  auto recorded = std::make_unique<CountingSequence>(&reads, 5);
  source = recorded.get();
  EXPECT_EQ(ReadAhead(std::move(recorded), 0).get(), source);
  EXPECT_EQ(reads.load(), 0);
}

}  // namespace
}  // namespace stitch
