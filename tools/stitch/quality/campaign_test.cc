// The merge campaign's draws: reproducible, within the ranges asked for, gusts apart, and
// arguments `stitch run` takes.

#include <algorithm>
#include <set>

#include <gtest/gtest.h>

#include "tools/stitch/quality/campaign.h"

namespace stitch {
namespace {

TEST(Campaign, TheSameSeedDrawsTheSameFlightsAndAnotherSeedOthers) {
  CampaignOptions options;
  std::set<std::vector<std::string>> drawn;
  for (int i = 0; i < 60; ++i) {
    EXPECT_EQ(CampaignRunArguments(DrawCampaignFlight(options, i)),
              CampaignRunArguments(DrawCampaignFlight(options, i)));
    drawn.insert(CampaignRunArguments(DrawCampaignFlight(options, i)));
  }
  EXPECT_EQ(drawn.size(), 60u);
  CampaignOptions other = options;
  other.seed = 2;
  EXPECT_NE(CampaignRunArguments(DrawCampaignFlight(options, 0)), CampaignRunArguments(DrawCampaignFlight(other, 0)));
}

TEST(Campaign, FlightsStayWithinTheRangesAndTheirGustsApart) {
  CampaignOptions options;
  int linked = 0, gusty = 0, long_flights = 0;
  std::set<int> budgets;
  for (int i = 0; i < 200; ++i) {
    const CampaignFlight f = DrawCampaignFlight(options, i);
    EXPECT_GE(f.frames, options.min_frames);
    EXPECT_LE(f.frames, options.max_frames);
    EXPECT_LE(f.gusts.size(), 4u);
    for (size_t g = 0; g < f.gusts.size(); ++g) {
      const auto [start, length] = f.gusts[g];
      EXPECT_GE(start, 40);
      EXPECT_GE(length, 6);
      EXPECT_LE(length, 20);
      EXPECT_LE(start + length + 40, f.frames);
      if (g > 0) {
        EXPECT_GE(start, f.gusts[g - 1].first + f.gusts[g - 1].second + 40);
      }
    }
    gusty += !f.gusts.empty();
    long_flights += f.frames > 1000;
    if (f.link) {
      ++linked;
      EXPECT_GE(f.loss, 0);
      EXPECT_LE(f.loss, 0.25);
      budgets.insert(f.budget);
    }
    const std::vector<std::string> args = CampaignRunArguments(f);
    EXPECT_EQ(std::count(args.begin(), args.end(), "--link") == 1, f.link);
    EXPECT_NE(std::find(args.begin(), args.end(), "--failures"), args.end());
  }
  // Half behind the link (every budget drawn), most with gusts, some longer than the default flight.
  EXPECT_GT(linked, 70);
  EXPECT_LT(linked, 130);
  EXPECT_EQ(budgets, (std::set<int>{0, 100000, 250000, 500000}));
  EXPECT_GT(gusty, 120);
  EXPECT_GT(long_flights, 40);
  // Without the link share, no flight is behind it.
  options.link_share = 0;
  for (int i = 0; i < 50; ++i) EXPECT_FALSE(DrawCampaignFlight(options, i).link);
}

}  // namespace
}  // namespace stitch
