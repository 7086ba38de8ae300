// What a run's outputs say about it, from its records alone (no services run).

#include "tools/stitch/launch/run_outputs.h"

#include <fstream>

#include <gtest/gtest.h>

#include "stitch/records/frame_record.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/tracking/tracking_result.h"

namespace stitch {
namespace {

// A run folder whose frames.tsv holds `records`.
void WriteFrames(const testing::TempDir& dir, const std::vector<FrameRecord>& records) {
  std::ofstream out(dir / "frames.tsv");
  out << FrameRecordHeader();
  for (const FrameRecord& r : records) out << FormatFrameRecord(r);
}

FrameRecord Frame(int index, const std::string& state, TrackingReason reason) {
  FrameRecord r;
  r.frame_index = index;
  r.t_ns = index * 50'000'000LL;
  r.state = state;
  r.reason = static_cast<int>(reason);
  return r;
}

bool SomeNoteSays(const RunInfo& info, const std::string& text) {
  for (const std::string& note : info.notes) {
    if (note.find(text) != std::string::npos) return true;
  }
  return false;
}

// A camera that never moved enough to begin a map (EuRoC's micro sequence on the ground): the
// summary says why no frame was localized instead of only "0 of 95".
TEST(RunOutputs, SaysWhyNoFrameWasLocalized) {
  testing::TempDir dir;
  std::vector<FrameRecord> records;
  for (int i = 0; i < 5; ++i) records.push_back(Frame(i, "INITIALIZING", TrackingReason::kInitFailed));
  records.push_back(Frame(5, "NOT_TRACKED", TrackingReason::kTooFewFeatures));
  WriteFrames(dir, records);
  RunInfo info;
  info.frames_total = 6;
  FinishRunOutputs(dir.path().string(), &info);
  EXPECT_TRUE(SomeNoteSays(info,
                           "no frame was localized: 5 initializing (initialization failed), 1 not tracked "
                           "(too few features)"));
  EXPECT_TRUE(SomeNoteSays(info, "min_parallax_deg"));
}

TEST(RunOutputs, SaysNothingOfTheKindWhereAFrameWasLocalized) {
  testing::TempDir dir;
  WriteFrames(dir, {Frame(0, "INITIALIZING", TrackingReason::kInitFailed), Frame(1, "OK", TrackingReason::kNone)});
  RunInfo info;
  info.frames_total = 2;
  FinishRunOutputs(dir.path().string(), &info);
  EXPECT_FALSE(SomeNoteSays(info, "no frame was localized"));
}

}  // namespace
}  // namespace stitch
