// The merge campaign end to end (stitch campaign): a short fixed subset of flights, one behind
// the rehearsed radio link, ends with every merge right; bad arguments are refused.

#include <filesystem>
#include <fstream>
#include <iterator>

#include <gtest/gtest.h>

#include "stitch/testing/temp_dir.h"
#include "tests/test_process.h"

namespace stitch {
namespace {

using testing::Bin;
using testing::ReadJson;
using testing::RunProgram;

// Seed 5 draws, for 200-260 frames, flight-000 with gusts and flight-001 behind a lossy link.
constexpr const char* kSeed = "5";

TEST(Campaign, AShortCampaignEndsWithEveryMergeRight) {
  testing::TempDir dir;
  const auto result = RunProgram(
      {Bin("stitch"), "campaign", "--runs", "2", "--seed", kSeed, "--frames", "200:260", "--out", dir / "campaign"},
      600);
  EXPECT_EQ(result.exit_code, 0) << result.output;
  EXPECT_NE(result.output.find("0 wrong merges, 0 failed"), std::string::npos) << result.output;
  const auto campaign = ReadJson(dir / "campaign/campaign.json");
  EXPECT_EQ(campaign["runs"], 2);
  EXPECT_EQ(campaign["wrong_merges"], 0);
  ASSERT_EQ(campaign["flights"].size(), 2u);
  bool linked = false, gusty = false;
  for (const auto& flight : campaign["flights"]) {
    const std::string command = flight["command"].get<std::string>();
    linked |= command.find("--link") != std::string::npos;
    gusty |= command.find("--failures none") == std::string::npos;
    EXPECT_FALSE(flight["failed"].get<bool>()) << flight.dump();
    EXPECT_GE(flight["figures"]["submaps"].get<double>(), 1) << flight.dump();
    EXPECT_EQ(flight["figures"]["wrong_merges"].get<double>(), 0) << flight.dump();
  }
  EXPECT_TRUE(linked) << "the subset must fly one flight behind the link: " << result.output;
  EXPECT_TRUE(gusty) << result.output;
  EXPECT_GE(campaign["submaps"].get<int>(), 3) << result.output;
}

// An earlier campaign's figures tabled again, running nothing: the flights are drawn again from
// its seed, the Markdown table goes between its markers and nowhere else.
TEST(Campaign, AnEarlierCampaignIsTabledWithoutRunningAnything) {
  testing::TempDir dir;
  {
    std::ofstream json(dir / "campaign.json");
    json << R"({"seed": 5, "runs": 1, "min_frames": 200, "max_frames": 260, "link_share": 0.5, "flights": [
      {"flight": "flight-000", "command": "build/bin/stitch run ...", "failed": false, "why": "",
       "figures": {"submaps": 2, "submaps_merged": 2, "wrong_merges": 1, "ate_m": 3.25,
                   "worst_submap_ate_in_map_m": 4.5}}]})";
    std::ofstream(dir / "doc.md") << "before\n<!-- merge-campaign -->\nold table\n<!-- /merge-campaign -->\nafter\n";
  }
  const auto result =
      RunProgram({Bin("stitch"), "campaign", "--from", dir / "campaign.json", "--markdown", dir / "doc.md"}, 60);
  EXPECT_EQ(result.exit_code, 1) << result.output;  // the campaign it tables had a wrong merge
  EXPECT_NE(result.output.find("1 flights (seed 5): 2 submaps, 2 of them"), std::string::npos) << result.output;
  EXPECT_NE(result.output.find("wrong merge in flight-000"), std::string::npos) << result.output;
  const std::string doc = testing::ReadWholeFile(dir / "doc.md");
  EXPECT_EQ(doc.rfind("before\n<!-- merge-campaign -->\n`build/bin/stitch campaign --runs 1 --seed 5`", 0), 0u) << doc;
  EXPECT_NE(doc.find("| flight-000 | 256 | 97:13 | - | 2 | 2 | 1 | 3.2500 | 4.5000 |"), std::string::npos) << doc;
  EXPECT_EQ(doc.find("old table"), std::string::npos) << doc;
  EXPECT_NE(doc.find("<!-- /merge-campaign -->\nafter\n"), std::string::npos) << doc;
  // Not a campaign's output: refused, and said to be.
  const auto refused = RunProgram({Bin("stitch"), "campaign", "--from", dir / "doc.md"}, 60);
  EXPECT_EQ(refused.exit_code, 2) << refused.output;
  EXPECT_NE(refused.output.find("not a campaign.json"), std::string::npos) << refused.output;
}

TEST(Campaign, BadArgumentsAreRefused) {
  testing::TempDir dir;
  for (const auto& [args, expected] : std::vector<std::pair<std::vector<std::string>, std::string>>{
           {{"--runs", "0"}, "--runs"},
           {{"--frames", "500:200"}, "--frames"},
           {{"--frames", "x"}, "--frames"},
           {{"--link-share", "2"}, "--link-share"},
       }) {
    std::vector<std::string> command = {Bin("stitch"), "campaign", "--out", dir / "c"};
    command.insert(command.end(), args.begin(), args.end());
    const auto result = RunProgram(command, 60);
    EXPECT_EQ(result.exit_code, 2) << result.output;
    EXPECT_NE(result.output.find(expected), std::string::npos) << result.output;
  }
}

}  // namespace
}  // namespace stitch
