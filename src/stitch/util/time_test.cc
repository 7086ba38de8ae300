#include "stitch/util/time.h"

#include <gtest/gtest.h>

#include "stitch/util/error.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

TEST(Time, ParsesSecondsExactly) {
  EXPECT_EQ(ParseSecondsToNs("1305031229.528748"), 1305031229528748000LL);
  EXPECT_EQ(ParseSecondsToNs("1403715273.262142976"), 1403715273262142976LL);
  EXPECT_EQ(ParseSecondsToNs("12"), 12000000000LL);
  EXPECT_EQ(ParseSecondsToNs("0.5"), 500000000LL);
  EXPECT_EQ(ParseSecondsToNs("-1.5"), -1500000000LL);
}

TEST(Time, RejectsWhatIsNotDecimalSeconds) {
  EXPECT_THROW(ParseSecondsToNs(""), Error);
  EXPECT_THROW(ParseSecondsToNs("abc"), Error);
  EXPECT_THROW(ParseSecondsToNs("1.5e3"), Error);
  EXPECT_THROW(ParseSecondsToNs("1.2.3"), Error);
}

TEST(Time, FormatRoundTrips) {
  for (int64_t t : {0LL, 1LL, 1403715273262142976LL, -2500000000LL}) {
    EXPECT_EQ(ParseSecondsToNs(FormatSeconds(t)), t);
  }
  EXPECT_EQ(FormatSeconds(1403715273262142976LL), "1403715273.262142976");
}

TEST(Rng, IsDeterministicAndUniform) {
  Rng a(42), b(42);
  double sum = 0;
  for (int i = 0; i < 10000; ++i) {
    const double x = a.Uniform();
    EXPECT_EQ(x, b.Uniform());
    ASSERT_GE(x, 0.0);
    ASSERT_LT(x, 1.0);
    sum += x;
  }
  EXPECT_NEAR(sum / 10000, 0.5, 0.02);
  Rng n(7);
  double mean = 0, sq = 0;
  for (int i = 0; i < 20000; ++i) {
    const double x = n.Normal();
    mean += x;
    sq += x * x;
  }
  EXPECT_NEAR(mean / 20000, 0.0, 0.03);
  EXPECT_NEAR(sq / 20000, 1.0, 0.04);
}

}  // namespace
}  // namespace stitch
