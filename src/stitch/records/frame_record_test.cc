#include "stitch/records/frame_record.h"

#include <gtest/gtest.h>

#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

FrameRecord Record(int frame_index) {
  FrameRecord r;
  r.frame_index = frame_index;
  r.t_ns = 50'000'000LL * frame_index;
  r.state = "OK";
  r.submap_id = 4294967296;
  r.world_from_cam = Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.5 * frame_index, 0, 10));
  r.num_features = 1000;
  r.tracked_points = 300 + frame_index;
  return r;
}

std::string Contents(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

TEST(FrameRecord, AppendingStartsANewFileWithTheHeaderAndGoesOnWithAnOldOne) {
  testing::TempDir dir;
  const std::string path = dir / "frames.tsv";
  AppendToFrameRecord(path) << FormatFrameRecord(Record(0));
  AppendToFrameRecord(path) << FormatFrameRecord(Record(1));
  EXPECT_EQ(Contents(path), FrameRecordHeader() + FormatFrameRecord(Record(0)) + FormatFrameRecord(Record(1)));
  const std::vector<FrameRecord> records = ReadFrameRecords(path);
  ASSERT_EQ(records.size(), 2u);
  EXPECT_EQ(records[1].frame_index, 1);
  EXPECT_EQ(records[1].tracked_points, 301);
}

// A tracker killed while writing a line leaves it cut short; the next tracker must not glue its
// first line onto it (that line would read as the cut one's frame, or make the file unreadable).
TEST(FrameRecord, AppendingDropsALastLineCutShortAndKeepsEveryWholeOne) {
  testing::TempDir dir;
  const std::string path = dir / "frames.tsv";
  const std::string whole = FrameRecordHeader() + FormatFrameRecord(Record(0)) + FormatFrameRecord(Record(1));
  for (const size_t cut : {size_t{1}, size_t{20}, FormatFrameRecord(Record(2)).size() - 1}) {
    std::ofstream(path, std::ios::trunc) << whole << FormatFrameRecord(Record(2)).substr(0, cut);
    AppendToFrameRecord(path) << FormatFrameRecord(Record(2));
    EXPECT_EQ(Contents(path), whole + FormatFrameRecord(Record(2))) << "cut after " << cut << " bytes";
    const std::vector<FrameRecord> records = ReadFrameRecords(path);
    ASSERT_EQ(records.size(), 3u);
    EXPECT_EQ(records[2].frame_index, 2);
    EXPECT_EQ(records[2].tracked_points, 302);
  }
  // Killed before even the header was whole.
  std::ofstream(path, std::ios::trunc) << FrameRecordHeader().substr(0, 10);
  AppendToFrameRecord(path) << FormatFrameRecord(Record(0));
  EXPECT_EQ(Contents(path), FrameRecordHeader() + FormatFrameRecord(Record(0)));
}

// A frame a new map placed once it initialized has a second, later line: it is the frame's
// record, with the tracking time and features of the first (the later line has none).
TEST(FrameRecord, AFramesLaterLineReplacesItsFirstKeepingItsTrackingTime) {
  testing::TempDir dir;
  const std::string path = dir / "frames.tsv";
  FrameRecord waiting = Record(0);
  waiting.state = "INITIALIZING";
  waiting.tracking_ms = 12.5;
  waiting.num_features = 900;
  FrameRecord placed = Record(0);
  placed.tracked_points = 77;
  placed.tracking_ms = 0;
  placed.num_features = 0;
  AppendToFrameRecord(path) << FormatFrameRecord(waiting) << FormatFrameRecord(Record(1)) << FormatFrameRecord(placed);
  const std::vector<FrameRecord> records = ReadFrameRecords(path);
  ASSERT_EQ(records.size(), 2u);
  EXPECT_EQ(records[0].frame_index, 0);
  EXPECT_EQ(records[0].state, "OK");
  EXPECT_EQ(records[0].tracked_points, 77);
  EXPECT_DOUBLE_EQ(records[0].tracking_ms, 12.5);
  EXPECT_EQ(records[0].num_features, 900);
  EXPECT_EQ(records[1].frame_index, 1);
}

// The tracker's words on a frame (how a map initialized, why a frame was not tracked) end the
// line; a message with line breaks or tabs stays one record, and a record without words (as
// written before there were any) reads with none.
TEST(FrameRecord, TheTrackersWordsOnAFrameEndItsLineAndReadBack) {
  testing::TempDir dir;
  const std::string path = dir / "frames.tsv";
  FrameRecord initialized = Record(0);
  initialized.note = "initialized from an essential matrix (homography's share of the score 0.31)\twith 54 points";
  FrameRecord refused = Record(1);
  refused.state = "INITIALIZING";
  refused.note = "essential matrix: parallax 0.4 deg,\n  need 1 ";
  AppendToFrameRecord(path) << FormatFrameRecord(initialized) << FormatFrameRecord(refused)
                            << FormatFrameRecord(Record(2));
  EXPECT_EQ(FormatFrameRecord(Record(2)).find("  "), std::string::npos);
  const std::vector<FrameRecord> records = ReadFrameRecords(path);
  ASSERT_EQ(records.size(), 3u);
  EXPECT_EQ(records[0].note,
            "initialized from an essential matrix (homography's share of the score 0.31) with 54 points");
  EXPECT_EQ(records[0].tracked_points, 300);
  EXPECT_EQ(records[1].note, "essential matrix: parallax 0.4 deg, need 1");
  EXPECT_EQ(records[1].state, "INITIALIZING");
  EXPECT_EQ(records[2].note, "");
  EXPECT_EQ(records[2].frame_index, 2);
}

TEST(FrameRecord, AppendingWhereNothingCanBeWrittenSaysWhy) {
  try {
    AppendToFrameRecord("/nonexistent-folder/frames.tsv");
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent-folder/frames.tsv"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace stitch
