// A tracker that crashes mid-flight and is restarted: submap ids stay unique, no frame is lost.
// The real programs over UDP multicast, the tracker killed with SIGKILL.

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>
#include <set>
#include <thread>

#include <gtest/gtest.h>

#include "services/common/bus.h"
#include "stitch/records/frame_record.h"
#include "stitch/records/keyframe_record.h"
#include "stitch/records/tracker_state.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/child_process.h"
#include "stitch/util/ids.h"
#include "tests/test_process.h"

namespace stitch {
namespace {

using namespace std::chrono_literals;
using testing::Bin;
using testing::ReadWholeFile;

// Whole records so far (the file is being written: its last line may be cut short).
size_t CountRecords(const std::string& path) {
  return std::filesystem::exists(path) ? ReadFrameRecords(path).size() : 0;
}

// The records in some of a frame record's lines (written to `path` to be read).
std::vector<FrameRecord> RecordsIn(const std::string& path, const std::string& lines) {
  std::ofstream(path, std::ios::binary) << lines;
  return ReadFrameRecords(path);
}

TEST(TrackerRestart, SubmapIdsStayUniqueAndNoFrameIsLost) {
  testing::TempDir dir;
  const std::string url = bus::UnusedLocalUdpUrl();
  const std::vector<std::string> common = {"--lcm-url", url, "--config",
                                           std::string(STITCH_SOURCE_DIR) + "/tests/short_flight.yaml"};
  const auto with = [&](std::vector<std::string> extra) {
    std::vector<std::string> args = common;
    args.insert(args.end(), extra.begin(), extra.end());
    return args;
  };
  const std::string frames = dir / "frames.tsv";
  const std::string state = dir / "tracker.state";
  const std::vector<std::string> tracker_args = with({"--record", frames, "--state", state});
  ChildProcess mapper("mapper", Bin("stitch-mapper"), with({"--record", dir.path().string()}), dir / "mapper.log");
  auto tracker = std::make_unique<ChildProcess>("tracker", Bin("stitch-tracker"), tracker_args, dir / "tracker1.log");
  std::this_thread::sleep_for(500ms);  // subscribed before the first frame
  ChildProcess ingest("ingest", Bin("stitch-ingest"), with({"--failures", "none"}), dir / "ingest.log");

  // Let the first tracker map half the strip, then kill it.
  const auto deadline = std::chrono::steady_clock::now() + 90s;
  while (CountRecords(frames) < 30 && std::chrono::steady_clock::now() < deadline) std::this_thread::sleep_for(20ms);
  ASSERT_GE(CountRecords(frames), 30u) << tracker->LogTail(10);
  EXPECT_EQ(tracker->Terminate(0ms), 128 + SIGKILL);
  // The first tracker's whole lines. The second appends after them (a line cut short by the kill
  // is dropped first); a frame in flight at the crash is tracked again, and its later line
  // replaces the first one's when the whole file is read, so which tracker wrote a record is told
  // by where its line lies, not by its place among the records.
  const std::string at_crash = ReadWholeFile(frames);
  const size_t first_trackers_bytes = at_crash.rfind('\n') + 1;
  tracker = std::make_unique<ChildProcess>("tracker", Bin("stitch-tracker"), tracker_args, dir / "tracker2.log");

  while (!ingest.Poll() && std::chrono::steady_clock::now() < deadline + 60s) std::this_thread::sleep_for(50ms);
  ASSERT_TRUE(ingest.Poll()) << ingest.LogTail(10);
  EXPECT_EQ(*ingest.Poll(), 0) << ingest.LogTail(10);
  std::this_thread::sleep_for(500ms);
  tracker->Terminate(15000ms);
  mapper.Terminate(60000ms);

  // Every frame was tracked by one of the two trackers (a frame in flight at the crash is
  // re-sent by ingest and may appear twice).
  const std::vector<FrameRecord> records = ReadFrameRecords(frames);
  std::set<int> indices;
  for (const auto& r : records) indices.insert(r.frame_index);
  EXPECT_EQ(indices.size(), 60u);
  EXPECT_EQ(*indices.rbegin(), 59);
  // Each tracker's lines apart.
  const std::string whole = ReadWholeFile(frames);
  ASSERT_GE(whole.size(), first_trackers_bytes);
  ASSERT_EQ(whole.compare(0, first_trackers_bytes, at_crash, 0, first_trackers_bytes), 0)
      << "the restarted tracker kept the first one's lines";
  const std::vector<FrameRecord> first_trackers =
      RecordsIn(dir / "first.tsv", at_crash.substr(0, first_trackers_bytes));
  const std::vector<FrameRecord> second_trackers = RecordsIn(dir / "second.tsv", whole.substr(first_trackers_bytes));
  ASSERT_FALSE(first_trackers.empty());
  // Before the crash: submap 1. After: a new submap with a new number, tracking again.
  std::set<int> before, after;
  int posed_after = 0;
  for (const FrameRecord& r : first_trackers) {
    if (r.submap_id >= 0) before.insert(SubmapNumber(SubmapId(r.submap_id)));
  }
  for (const FrameRecord& r : second_trackers) {
    if (r.submap_id >= 0) after.insert(SubmapNumber(SubmapId(r.submap_id)));
    posed_after += r.state == "OK";
  }
  // (A tracker starved by a loaded machine may lose tracking and start another submap before
  // the crash; under AddressSanitizer beside other tests the first one once made submaps 1 and
  // 2. The numbers must still never repeat.)
  // On a failure: each tracker's lines (frame, state, submap) and both trackers' logs.
  std::string story;
  for (const auto* lines : {&first_trackers, &second_trackers}) {
    story += lines == &first_trackers ? "first tracker:\n" : "second tracker:\n";
    for (const FrameRecord& r : *lines) {
      story += std::to_string(r.frame_index) + " " + r.state + " " +
               (r.submap_id < 0 ? "-" : SubmapName(SubmapId(r.submap_id))) + "\n";
    }
  }
  const auto log_of = [&](const char* name) { return std::string(name) + ":\n" + ReadWholeFile(dir / name); };
  story += log_of("tracker1.log") + log_of("tracker2.log");
  ASSERT_FALSE(before.empty()) << story;
  ASSERT_FALSE(after.empty()) << story;
  EXPECT_EQ(*before.begin(), 1) << story;
  EXPECT_EQ(*after.begin(), *before.rbegin() + 1) << "the restarted tracker goes on from the next number\n" << story;
  EXPECT_GE(posed_after, static_cast<int>(second_trackers.size()) - 6) << story;
  // Every keyframe the trackers made reached the mapper, but for the one of the frame being
  // tracked at the crash: that frame was not acknowledged and was tracked again.
  std::set<std::pair<int64_t, int>> mapped;  // submap, frame index
  for (const KeyframeRecord& k : ReadKeyframeRecords(dir / "keyframes.tsv")) mapped.emplace(k.submap_id, k.frame_index);
  int made = 0;
  for (const auto* lines : {&first_trackers, &second_trackers}) {
    for (const FrameRecord& r : *lines) {
      if (!r.is_keyframe || (lines == &first_trackers && r.frame_index == first_trackers.back().frame_index)) continue;
      ++made;
      EXPECT_TRUE(mapped.count({r.submap_id, r.frame_index}))
          << "keyframe of frame " << r.frame_index << " in submap " << r.submap_id << " not mapped";
    }
  }
  EXPECT_GE(made, 6);
  EXPECT_EQ(ReadNextSubmapNumber(state), *after.rbegin() + 1);
  const std::string text = ReadWholeFile(dir / "tracker2.log");
  EXPECT_NE(text.find("resuming: submaps continue from number " + std::to_string(*after.begin())), std::string::npos)
      << text;
}

}  // namespace
}  // namespace stitch
