// The real-time margin's search (FindMargin) on a machine whose capacity is known: it keeps up
// at every speed up to its capacity and drops a growing share of frames beyond it.

#include "tools/stitch/quality/margin.h"

#include <gtest/gtest.h>

#include "stitch/util/error.h"

namespace stitch {
namespace {

// A case that keeps up to `capacity` times the camera's rate and drops what exceeds it.
struct Machine {
  double capacity;
  std::vector<double> played;
  MarginTrial operator()(double speed) {
    played.push_back(speed);
    MarginTrial t;
    t.dropped_share = speed <= capacity ? 0.005 : 1 - capacity / speed;
    return t;
  }
};

Margin Search(Machine* machine, const MarginOptions& options = MarginOptions()) {
  return FindMargin([machine](double speed) { return (*machine)(speed); }, options);
}

TEST(RealtimeMargin, FindsTheFastestSpeedThatKeepsUpWithinItsResolution) {
  for (const double capacity : {1.0, 1.7, 2.9, 5.3}) {
    Machine machine{capacity, {}};
    const Margin margin = Search(&machine);
    EXPECT_FALSE(margin.capped);
    EXPECT_LE(margin.speed, capacity) << capacity;
    EXPECT_GT(margin.speed * 1.1, capacity * 0.99) << "within the resolution of " << capacity;
    EXPECT_EQ(machine.played.front(), 1) << "starts at the camera's rate";
    EXPECT_LE(machine.played.size(), 8u) << "doubling then bisecting, not a sweep";
    for (const MarginTrial& t : margin.trials) EXPECT_EQ(t.kept_up, t.speed <= capacity) << t.speed;
  }
}

TEST(RealtimeMargin, AMachineSlowerThanTheCameraHasAMarginBelowOne) {
  Machine machine{0.6, {}};
  const Margin margin = Search(&machine);
  EXPECT_LE(margin.speed, 0.6);
  EXPECT_GT(margin.speed * 1.1, 0.6 * 0.99);
  EXPECT_EQ(machine.played[0], 1);
  EXPECT_EQ(machine.played[1], 0.5) << "halves until it keeps up";
}

TEST(RealtimeMargin, NeverKeepingUpIsNoMarginAndAlwaysKeepingUpIsCapped) {
  Machine slow{0.1, {}};
  const Margin none = Search(&slow);
  EXPECT_EQ(none.speed, 0);
  EXPECT_EQ(slow.played.back(), 0.25) << "down to the slowest speed, no further";
  Machine fast{100, {}};
  const Margin capped = Search(&fast);
  EXPECT_TRUE(capped.capped);
  EXPECT_EQ(capped.speed, 8);
  EXPECT_EQ(fast.played, (std::vector<double>{1, 2, 4, 8}));
}

TEST(RealtimeMargin, AShareAboveTheLimitIsNotKeepingUp) {
  // 0.5% dropped within capacity keeps up at a 1% limit, not at a 0.1% limit.
  Machine machine{3, {}};
  MarginOptions strict;
  strict.max_dropped_share = 0.001;
  EXPECT_EQ(Search(&machine, strict).speed, 0);
  MarginOptions bad;
  bad.lowest_speed = 2;
  EXPECT_THROW(Search(&machine, bad), Error);
}

}  // namespace
}  // namespace stitch
