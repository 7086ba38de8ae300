// The onboard / ground split over a lossy link: `stitch run --link` puts the merger on a bus of
// its own behind two stitch-link bridges; with --netns the aircraft's services and the ground's
// run in two network namespaces joined by a veth pair, as across a routed radio link. The merged
// result must match the unsplit run's, with every keyframe the mapper kept in the merged map.

#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "stitch/io/trajectory.h"
#include "stitch/records/keyframe_pictures.h"
#include "stitch/records/keyframe_record.h"
#include "stitch/records/merger_records.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/ids.h"
#include "tests/test_process.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

using testing::Bin;
using testing::RunProgram;

using testing::ReadJson;
const std::string kShortFlight = testing::ShortFlightConfig();

// The mapper's kept keyframes (keyframes.tsv) and the merged ones (keyframes_merged.tsv).
std::set<int64_t> KeptKeyframes(const std::string& path) {
  std::set<int64_t> ids;
  for (const KeyframeRecord& r : ReadKeyframeRecords(path)) {
    if (!r.culled) ids.insert(r.keyframe_id);
  }
  return ids;
}
std::set<int64_t> MergedKeyframes(const std::string& path) {
  std::set<int64_t> ids;
  for (const MergedKeyframeRecord& r : ReadMergedKeyframeRecords(path)) ids.insert(r.keyframe.value);
  return ids;
}

struct RunResult {
  fs::path dir;
  nlohmann::json report, info;
  std::set<int64_t> kept, merged;
  size_t posed = 0, posed_on_the_ground = 0;  // frames in trajectory.tum and trajectory_ground.tum
  std::string output;
};

RunResult RunStitch(const fs::path& out, const std::vector<std::string>& extra) {
  std::vector<std::string> args = {Bin("stitch"), "run",     "--config", kShortFlight, "--failures",
                                   "30:6",        "--quiet", "--out",    out.string()};
  args.insert(args.end(), extra.begin(), extra.end());
  const auto result = RunProgram(args, 240);
  EXPECT_EQ(result.exit_code, 0) << result.output;
  RunResult run;
  run.dir = out;
  run.output = result.output;
  if (result.exit_code != 0) return run;
  run.report = ReadJson((out / "report.json").string());
  run.info = ReadJson((out / "run.json").string());
  run.kept = KeptKeyframes((out / "keyframes.tsv").string());
  run.merged = MergedKeyframes((out / "keyframes_merged.tsv").string());
  run.posed = Trajectory::ReadTum((out / "trajectory.tum").string()).size();
  if (std::filesystem::exists(out / "trajectory_ground.tum")) {
    run.posed_on_the_ground = Trajectory::ReadTum((out / "trajectory_ground.tum").string()).size();
  }
  return run;
}

// Where kept keyframes are missing from the merged map: which ones (submap:number), and what the
// merger and the mapper said of asking for them again (the run folder is deleted with the test).
std::string WhyKeyframesAreMissing(const RunResult& run) {
  std::ostringstream why;
  why << "missing:";
  for (int64_t id : run.kept) {
    if (!run.merged.count(id)) why << " " << SubmapName(SubmapOf(KeyframeId(id))) << "#" << IndexOf(KeyframeId(id));
  }
  for (const char* service : {"merger", "mapper"}) {
    std::ifstream log(run.dir / "logs" / (std::string(service) + ".log"));
    std::vector<std::string> said;
    for (std::string line; std::getline(log, line);) {
      for (const char* word : {"again", "never received", "whole", "gave up", "request", "linger", "stopped"}) {
        if (line.find(word) != std::string::npos) {
          said.push_back(line);
          break;
        }
      }
    }
    why << "\n" << service << ".log (" << said.size() << " lines on asking again, the last 25):";
    for (size_t i = said.size() > 25 ? said.size() - 25 : 0; i < said.size(); ++i) why << "\n  " << said[i];
  }
  return why.str();
}

// The split run against the unsplit one: every submap merged, every kept keyframe in the
// merged map, the trajectory as good within a few centimetres, and the link really lossy.
void ExpectSameResult(const RunResult& plain, const RunResult& split, const std::string& what) {
  ASSERT_FALSE(split.report.is_null()) << what;
  EXPECT_EQ(split.report["submaps"], plain.report["submaps"]) << what;
  EXPECT_EQ(split.report["submaps_merged"], split.report["submaps"]) << what << ": a submap is missing";
  EXPECT_GT(split.kept.size(), 10u) << what;
  EXPECT_EQ(split.merged, split.kept) << what << ": keyframes missing from the merged map\n"
                                      << (split.merged != split.kept ? WhyKeyframesAreMissing(split) : "");
  EXPECT_NEAR(split.report["ate_rmse_m"].get<double>(), plain.report["ate_rmse_m"].get<double>(), 0.05) << what;
  // The merger's verdict on each pair of submaps is in the report: the merges, none refused.
  ASSERT_TRUE(split.report.contains("merges")) << what;
  int merged = 0;
  for (const auto& edge : split.report["merges"]) {
    const std::string status = edge["status"].get<std::string>();
    merged += status == "merged";
    EXPECT_EQ(status.find("refused"), std::string::npos) << what << ": " << edge.dump();
  }
  EXPECT_EQ(merged + 1, split.report["submaps_merged"].get<int>()) << what << ": " << split.report["merges"].dump();
  // The pose stream crossed the link too: the ground placed (nearly) every frame of the largest map.
  EXPECT_GE(split.posed_on_the_ground, split.posed * 9 / 10)
      << what << ": " << split.posed_on_the_ground << " of " << split.posed << " frames in the ground's trajectory";
  // The keyframes' pictures crossed too, behind everything else: (nearly) all the plain run's.
  const size_t pictures = ReadKeyframePictureIndex(plain.dir.string()).size();
  EXPECT_GE(pictures, 3u) << what;
  EXPECT_GE(ReadKeyframePictureIndex(split.dir.string()).size(), pictures * 3 / 4) << what;
  EXPECT_FALSE(split.info["link"].get<std::string>().empty()) << what;
  const auto figures = split.info["link_figures"];
  ASSERT_EQ(figures.size(), 2u) << what << "\n" << split.output;
  for (const auto& line : figures) {
    const std::string text = line.get<std::string>();
    EXPECT_EQ(text.find("gave up"), std::string::npos) << what << ": " << text;
    if (text.rfind("link-aircraft", 0) == 0) {
      EXPECT_NE(text.find("dropped on purpose"), std::string::npos) << text;
      EXPECT_EQ(text.find("repaired 0 fragments"), std::string::npos) << text;
    }
  }
}

class LinkSplit : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    plain_dir_ = new stitch::testing::TempDir();
    plain_ = new RunResult(RunStitch(plain_dir_->path() / "plain", {}));
  }
  static void TearDownTestSuite() {
    delete plain_;
    delete plain_dir_;
  }
  static stitch::testing::TempDir* plain_dir_;
  static RunResult* plain_;
};
stitch::testing::TempDir* LinkSplit::plain_dir_ = nullptr;
RunResult* LinkSplit::plain_ = nullptr;

TEST_F(LinkSplit, TheMergerBehindALossyLinkOnThisMachineGetsEverySubmap) {
  ASSERT_FALSE(plain_->report.is_null());
  testing::TempDir dir;
  const RunResult split = RunStitch(
      dir.path() / "link", {"--link", "--link-loss", "0.2", "--link-delay-ms", "100", "--link-budget", "2000000"});
  ExpectSameResult(*plain_, split, "loopback link, 20% loss");
}

// Whether this machine lets us make network namespaces (root, iproute2, a kernel that allows it).
std::string WhyNoNamespaces() {
  if (geteuid() != 0) return "not root";
  if (access("/usr/sbin/ip", X_OK) != 0 && access("/sbin/ip", X_OK) != 0) return "iproute2 (ip) is not installed";
  const std::string name = "stitch-probe-" + std::to_string(getpid());
  const std::string ip = access("/usr/sbin/ip", X_OK) == 0 ? "/usr/sbin/ip" : "/sbin/ip";
  const auto add = RunProgram({ip, "netns", "add", name}, 20);
  if (add.exit_code != 0) return "`ip netns add` failed: " + add.output;
  RunProgram({ip, "netns", "delete", name}, 20);
  return "";
}

TEST_F(LinkSplit, AircraftAndGroundInTwoNetworkNamespacesAt5And20PercentLoss) {
  const std::string why = WhyNoNamespaces();
  if (!why.empty())
    GTEST_SKIP() << "network namespaces are not available here (" << why << "); the split test needs them";
  ASSERT_FALSE(plain_->report.is_null());
  for (const char* loss : {"0.05", "0.2"}) {
    testing::TempDir dir;
    const RunResult split = RunStitch(dir.path() / "netns", {"--netns", "--link-loss", loss, "--link-delay-ms", "100"});
    ExpectSameResult(*plain_, split, std::string("two namespaces, loss ") + loss);
    EXPECT_NE(split.output.find("two network namespaces"), std::string::npos);
  }
  // Nothing is left behind.
  const auto list = RunProgram({access("/usr/sbin/ip", X_OK) == 0 ? "/usr/sbin/ip" : "/sbin/ip", "netns", "list"}, 20);
  EXPECT_EQ(list.output.find("stitch-"), std::string::npos) << list.output;
}

}  // namespace
}  // namespace stitch
