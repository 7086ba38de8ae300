#include "stitch/geo/receiver_clock.h"

#include <cmath>
#include <cstdlib>

#include <gtest/gtest.h>

#include "stitch/util/rng.h"

namespace stitch {
namespace {

constexpr int64_t kSecond = 1'000'000'000;

// A 5 Hz receiver whose fixes arrive 50 ms after their epoch plus up to 300 ms of jitter, on a
// local clock 1000 s ahead of the receiver's: stamped by the receiver's time, each fix lands
// within a few milliseconds of its epoch plus the quickest delay; stamped on arrival, up to
// 300 ms off.
TEST(ReceiverClock, FixesKeepTheReceiversTimesWhateverTheirArrivalsJitter) {
  ReceiverClock clock;
  Rng rng(3);
  double worst_stamped = 0, worst_arrival = 0;
  for (int i = 0; i < 300; ++i) {
    const int64_t epoch = 100 * kSecond + i * kSecond / 5;
    const int64_t arrived = epoch + 1000 * kSecond + 50'000'000 + static_cast<int64_t>(rng.Uniform(0, 0.3) * 1e9);
    const int64_t stamp = clock.Stamp(epoch, arrived);
    const int64_t truth = epoch + 1000 * kSecond + 50'000'000;
    EXPECT_GE(stamp, truth) << "never earlier than the quickest delay allows";
    if (i >= 25) {  // after 5 s
      worst_stamped = std::max(worst_stamped, static_cast<double>(stamp - truth) * 1e-9);
      worst_arrival = std::max(worst_arrival, static_cast<double>(arrived - truth) * 1e-9);
    }
  }
  EXPECT_LT(worst_stamped, 0.03);
  EXPECT_GT(worst_arrival, 0.25);
  EXPECT_EQ(clock.restarts(), 0);
}

// The local clock stepped: back 5 s (the offset shrinks: at once), or a receiver restarted and
// counts from its boot again (its times fall back by hours: at once). A delay that grows by
// seconds (a queue on the link) keeps the offset until the window passes it by.
TEST(ReceiverClock, AJumpStartsOverAQueueDoesNot) {
  ReceiverClock clock(/*window_s=*/30, /*max_jump_s=*/2, /*max_delay_s=*/10);
  int64_t receiver = 0, local = 500 * kSecond;
  const auto step = [&](int64_t delay_ns) {
    receiver += kSecond / 5;
    local += kSecond / 5;
    return clock.Stamp(receiver, local + delay_ns) - local;  // the stamp against the epoch's local time
  };
  for (int i = 0; i < 50; ++i) EXPECT_EQ(step(100'000'000), 100'000'000);
  // A queue: fixes arrive 4 s late; they keep their epochs.
  for (int i = 0; i < 20; ++i) EXPECT_EQ(step(4 * kSecond), 100'000'000);
  EXPECT_EQ(clock.restarts(), 0);
  // The local clock stepped back 5 s: the offset follows at once.
  local -= 5 * kSecond;
  EXPECT_EQ(step(100'000'000), 100'000'000);
  EXPECT_EQ(clock.restarts(), 1);
  // The receiver restarted: its time counts from 0 again.
  receiver = -kSecond / 5;
  EXPECT_EQ(step(100'000'000), 100'000'000);
  EXPECT_EQ(clock.restarts(), 2);
  // A drift of the local clock (100 ppm) is followed through the window.
  for (int i = 0; i < 600; ++i) {
    local += 20'000;  // 100 ppm of 0.2 s
    const int64_t stamped = step(100'000'000);
    EXPECT_LE(std::llabs(stamped - 100'000'000), 3'500'000) << i;
  }
}

// Whatever a receiver sends for its time, no arithmetic overflows (UBSan would say) and the stamp
// stays on the local clock's side of the bound.
TEST(ReceiverClock, AnyReceiverTimeIsTaken) {
  ReceiverClock clock;
  const int64_t now = 1'764'000'000 * kSecond;
  for (const int64_t sent : {INT64_MAX, INT64_MIN, int64_t{0}, now, -now, INT64_MAX / 2}) {
    const int64_t stamp = clock.Stamp(sent, now);
    EXPECT_LE(std::llabs(stamp - now), int64_t{1} << 62) << sent;
  }
}

}  // namespace
}  // namespace stitch
