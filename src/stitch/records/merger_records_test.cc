// Each record file read back as written, and a malformed line named.

#include "stitch/records/merger_records.h"

#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "stitch/records/pose_record.h"
#include "stitch/records/run_info.h"
#include "stitch/records/tracker_state.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

const Sim3d kSim3(1.75, Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized())),
                  Eigen::Vector3d(12.5, -3.25, 0.125));

void ExpectNear(const Sim3d& a, const Sim3d& b) {
  EXPECT_NEAR(a.scale, b.scale, 1e-8);
  EXPECT_LT(a.rotation.angularDistance(b.rotation), 1e-8);
  EXPECT_LT((a.translation - b.translation).norm(), 1e-7);
}

void AppendLine(const std::string& path, const std::string& line) {
  std::ofstream out(path, std::ios::app);
  out << line << "\n";
}

// Reading `path` after a bad line throws an error naming the file and the line.
template <class Read>
void ExpectMalformedLineNamed(const std::string& path, Read read, int line) {
  try {
    read(path);
    ADD_FAILURE() << "no error for a malformed line";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(path + ":" + std::to_string(line)), std::string::npos) << e.what();
  }
}

TEST(MergerRecords, SubmapsReadBackAsWritten) {
  testing::TempDir dir;
  const std::string path = dir / "submaps.tsv";
  const std::vector<SubmapRecord> written = {{MakeSubmapId(0, 1), 0, MakeSubmapId(0, 2), 41, 3020, true, kSim3},
                                             {MakeSubmapId(3, 7), 1, MakeSubmapId(3, 7), 5, 100, false, Sim3d()}};
  WriteSubmapRecords(path, written);
  const std::vector<SubmapRecord> read = ReadSubmapRecords(path);
  ASSERT_EQ(read.size(), 2u);
  EXPECT_EQ(read[0].submap, written[0].submap);
  EXPECT_EQ(read[0].component, 0);
  EXPECT_EQ(read[0].root, written[0].root);
  EXPECT_EQ(read[0].keyframes, 41u);
  EXPECT_EQ(read[0].points, 3020u);
  EXPECT_TRUE(read[0].closed);
  ExpectNear(read[0].world_from_submap, kSim3);
  EXPECT_EQ(read[1].submap, written[1].submap);
  EXPECT_FALSE(read[1].closed);
  AppendLine(path, "17 0 17 3 4");
  ExpectMalformedLineNamed(path, ReadSubmapRecords, 4);
}

TEST(MergerRecords, MergedKeyframesReadBackAsWritten) {
  testing::TempDir dir;
  const std::string path = dir / "keyframes_merged.tsv";
  const KeyframeId id = MakeKeyframeId(MakeSubmapId(2, 5), 17);
  WriteMergedKeyframeRecords(path, {{id, 3, kSim3, 412, 1305031102175304000}});
  const auto read = ReadMergedKeyframeRecords(path);
  ASSERT_EQ(read.size(), 1u);
  EXPECT_EQ(read[0].keyframe, id);
  EXPECT_EQ(read[0].component, 3);
  ExpectNear(read[0].world_from_cam, kSim3);
  EXPECT_EQ(read[0].frame_index, 412);
  EXPECT_EQ(read[0].t_ns, 1305031102175304000);
  // A line from before the timestamps still reads; one with a frame but no time does not.
  AppendLine(path, std::to_string(id.value) + " " + std::to_string(SubmapOf(id).value) + " 0 1 0 0 0 1 0 0 0");
  EXPECT_EQ(ReadMergedKeyframeRecords(path).size(), 2u);
  AppendLine(path, std::to_string(id.value) + " " + std::to_string(SubmapOf(id).value) + " 0 1 0 0 0 1 0 0 0 7");
  ExpectMalformedLineNamed(path, ReadMergedKeyframeRecords, 4);
  WriteMergedKeyframeRecords(path, {{id, 3, kSim3, 412, 1305031102175304000}});
  // The submap column must be the keyframe's.
  AppendLine(path, std::to_string(id.value) + " 99 0 1 0 0 0 1 0 0 0");
  ExpectMalformedLineNamed(path, ReadMergedKeyframeRecords, 3);
}

TEST(MergerRecords, ConnectionsReadBackAsWritten) {
  testing::TempDir dir;
  const std::string path = dir / "connections.tsv";
  const KeyframeId a = MakeKeyframeId(MakeSubmapId(0, 1), 3), b = MakeKeyframeId(MakeSubmapId(0, 2), 9);
  ConnectionRecord written{a, b, 57, 23.125, kSim3};
  written.verified_by = "projection";
  written.bearing_spread_a = 0.125;
  written.bearing_spread_b = 0.25;
  written.line_ratio = 0.0625;
  written.depth_disagreement = 0.5;
  written.verdict = "degenerate: points near a line";
  WriteConnectionRecords(path, {written});
  const auto read = ReadConnectionRecords(path);
  ASSERT_EQ(read.size(), 1u);
  EXPECT_EQ(read[0].verified_by, "projection");
  EXPECT_DOUBLE_EQ(read[0].bearing_spread_a, 0.125);
  EXPECT_DOUBLE_EQ(read[0].bearing_spread_b, 0.25);
  EXPECT_DOUBLE_EQ(read[0].line_ratio, 0.0625);
  EXPECT_DOUBLE_EQ(read[0].depth_disagreement, 0.5);
  EXPECT_EQ(read[0].verdict, "degenerate: points near a line");
  EXPECT_EQ(read[0].keyframe_a, a);
  EXPECT_EQ(read[0].keyframe_b, b);
  EXPECT_EQ(read[0].map_points, 57);
  EXPECT_NEAR(read[0].median_angle_deg, 23.125, 1e-9);
  ExpectNear(read[0].b_from_a, kSim3);
  AppendLine(path, "1 2 x");
  ExpectMalformedLineNamed(path, ReadConnectionRecords, 3);
}

TEST(MergerRecords, SubmapEdgesReadBackAsWritten) {
  testing::TempDir dir;
  const std::string path = dir / "edges.tsv";
  SubmapEdgeRecord written;
  written.a = MakeSubmapId(0, 2);
  written.b = MakeSubmapId(0, 3);
  written.strength = 51.375;
  written.connected_frames = 11;
  written.map_points = 346;
  written.disagreeing_frames = 4;
  written.median_angle_deg = 8.25;
  written.agreement = 0.5625;
  written.status = "refused: its connected frames disagree: 56% of the points agree (needs 60%)";
  WriteSubmapEdgeRecords(path, {written});
  const auto read = ReadSubmapEdgeRecords(path);
  ASSERT_EQ(read.size(), 1u);
  EXPECT_EQ(read[0].a, written.a);
  EXPECT_EQ(read[0].b, written.b);
  EXPECT_DOUBLE_EQ(read[0].strength, 51.375);
  EXPECT_EQ(read[0].connected_frames, 11);
  EXPECT_EQ(read[0].map_points, 346);
  EXPECT_EQ(read[0].disagreeing_frames, 4);
  EXPECT_DOUBLE_EQ(read[0].median_angle_deg, 8.25);
  EXPECT_DOUBLE_EQ(read[0].agreement, 0.5625);
  EXPECT_EQ(read[0].status, written.status);
  AppendLine(path, "1 2 3.0 1 2 0 4.0 0.5");  // no status
  ExpectMalformedLineNamed(path, ReadSubmapEdgeRecords, 3);
}

TEST(MergerRecords, RetrievalQueriesReadBackAsWritten) {
  testing::TempDir dir;
  const std::string path = dir / "retrieval.tsv";
  RetrievalRecord full;
  full.keyframe = KeyframeId(4294967310);
  full.previous = KeyframeId(4294967309);
  full.nearby = KeyframeId(4294967305);
  full.n0 = 398;
  full.n1 = 201;
  full.s0 = 0.1905;
  full.s1 = 0.0812;
  full.k = 0.505;
  full.l = 0.426;
  full.shared_word_candidates = 12;
  full.candidates = {KeyframeId(8589934600), KeyframeId(8589934601)};
  full.connected = {KeyframeId(8589934600)};
  full.verification = {{40, 31}, {14, 0}};
  full.loops = {KeyframeId(4294967297)};
  RetrievalRecord skipped;
  skipped.keyframe = KeyframeId(4294967296);
  skipped.skipped = "first keyframe of its submap";
  WriteRetrievalRecords(path, {full, skipped});
  const auto read = ReadRetrievalRecords(path);
  ASSERT_EQ(read.size(), 2u);
  EXPECT_EQ(read[0].keyframe, full.keyframe);
  EXPECT_EQ(read[0].nearby, full.nearby);
  EXPECT_EQ(read[0].n1, 201);
  EXPECT_NEAR(read[0].s1, 0.0812, 1e-9);
  EXPECT_NEAR(read[0].l, 0.426, 1e-9);
  EXPECT_EQ(read[0].candidates, full.candidates);
  EXPECT_EQ(read[0].connected, full.connected);
  EXPECT_EQ(read[0].verification, full.verification);
  EXPECT_TRUE(read[0].loop_candidates.empty());
  EXPECT_EQ(read[0].loops, full.loops);
  EXPECT_TRUE(read[0].skipped.empty());
  EXPECT_EQ(read[1].skipped, "first keyframe of its submap");
  EXPECT_FALSE(read[1].previous.valid());
  AppendLine(path, "1\t2\t3");
  ExpectMalformedLineNamed(path, ReadRetrievalRecords, 4);
}

TEST(MergerRecords, MergeLogReadsBackAsWritten) {
  testing::TempDir dir;
  const std::string path = dir / "merge_log.tsv";
  const std::vector<MergeLogRecord> written = {{"keyframe of submap 0:1", "0:1", "", "0:1"},
                                               {"submap 0:2 closed", "0:2", "0:1", "0:1 0:2"}};
  WriteMergeLog(path, written);
  const auto read = ReadMergeLog(path);
  ASSERT_EQ(read.size(), 2u);
  EXPECT_EQ(read[0].event, "keyframe of submap 0:1");
  EXPECT_EQ(read[0].unconnected, "");
  EXPECT_EQ(read[1].unconnected, "0:1");
  EXPECT_EQ(read[1].merged_maps, "0:1 0:2");
  AppendLine(path, "only an event");
  ExpectMalformedLineNamed(path, ReadMergeLog, 4);
}

TEST(Records, PosesReadBackAsWritten) {
  testing::TempDir dir;
  const std::string path = dir / "poses.tsv";
  PoseRecord pose;
  pose.frame_index = 12;
  pose.t_ns = 1403715273262142976;
  pose.submap_id = MakeSubmapId(0, 2).value;
  pose.component = 1;
  pose.is_keyframe = true;
  pose.world_from_cam = Rigid3d(kSim3.rotation, kSim3.translation);
  WritePoseRecords(path, {pose});
  const auto read = ReadPoseRecords(path);
  ASSERT_EQ(read.size(), 1u);
  EXPECT_EQ(read[0].t_ns, pose.t_ns);
  EXPECT_EQ(read[0].submap_id, pose.submap_id);
  EXPECT_TRUE(read[0].is_keyframe);
  EXPECT_LT((read[0].world_from_cam.translation - pose.world_from_cam.translation).norm(), 1e-6);
  AppendLine(path, "13 0 1");
  ExpectMalformedLineNamed(path, ReadPoseRecords, 3);
}

TEST(Records, TrackerStateKeepsTheNextSubmapNumber) {
  testing::TempDir dir;
  const std::string path = dir / "tracker.state";
  EXPECT_EQ(ReadNextSubmapNumber(path), 0) << "no file yet";
  WriteNextSubmapNumber(path, 42);
  EXPECT_EQ(ReadNextSubmapNumber(path), 42);
  EXPECT_FALSE(std::filesystem::exists(path + ".partial"));
  std::ofstream(path) << "next_submap_number 70000\n";
  EXPECT_THROW(ReadNextSubmapNumber(path), Error);
  std::ofstream(path) << "garbage\n";
  EXPECT_THROW(ReadNextSubmapNumber(path), Error);
}

TEST(Records, RunInfoReadsBackAsWritten) {
  testing::TempDir dir;
  RunInfo info;
  info.source = "synthetic";
  info.frames_total = 1000;
  info.failures = "200:12";
  info.on_loss = "submap";
  info.pacing = "lockstep";
  info.notes = {"a note"};
  info.interrupted = true;
  SaveRunInfo(info, dir.path().string());
  const RunInfo read = LoadRunInfo(dir.path().string());
  EXPECT_EQ(read.frames_total, 1000);
  EXPECT_EQ(read.failures, "200:12");
  EXPECT_TRUE(read.interrupted);
  EXPECT_EQ(read.notes, info.notes);
  std::ofstream(dir / "run.json") << "{\"source\": 3";
  EXPECT_THROW(LoadRunInfo(dir.path().string()), Error);
}

}  // namespace
}  // namespace stitch

namespace stitch {
namespace {

// The parts that views join, where GNSS junctions join a map's parts: 1-2 by views, 3 and 4 by
// views, the two parts by GNSS, 5 refused.
TEST(SubmapEdgeRecords, ThePartsViewsJoinAreFoundAcrossGnssJunctions) {
  const auto edge = [](int a, int b, const std::string& status) {
    SubmapEdgeRecord e;
    e.a = SubmapId(a);
    e.b = SubmapId(b);
    e.status = status;
    return e;
  };
  const std::map<int64_t, int64_t> parts =
      ViewJoinedParts({edge(3, 4, "merged"), edge(1, 2, "merged"), edge(2, 3, "joined by GNSS (+-0.50 m)"),
                       edge(4, 5, "refused: 1 agreeing connected frame (needs 2)")});
  EXPECT_EQ(parts, (std::map<int64_t, int64_t>{{1, 1}, {2, 1}, {3, 3}, {4, 3}, {5, 5}}));
  EXPECT_TRUE(JoinedByGnss(edge(2, 3, "joined by GNSS (+-0.50 m)")));
  EXPECT_FALSE(JoinedByGnss(edge(1, 2, "merged")));
}

}  // namespace
}  // namespace stitch
