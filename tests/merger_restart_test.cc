// The merger killed with SIGKILL halfway through a flight and restarted with the same state
// folder: it resumes from its journal and ends with the same merged map as a merger that ran
// through, and `stitch map` rebuilds that map from the journal. The real stitch-merger over UDP
// multicast; the submap updates are those a mapper sent in an in-process run of a strip with a
// gust (two submaps to merge).

#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <sstream>
#include <thread>

#include <gtest/gtest.h>

#include "services/common/bus.h"
#include "services/common/convert.h"
#include "services/common/map_convert.h"
#include "services/common/update_journal.h"
#include "stitch/config/stitch_config.h"
#include "stitch/eval/evaluation.h"
#include "stitch/geo/gnss_fix.h"
#include "stitch/io/ply.h"
#include "stitch/io/trajectory.h"
#include "stitch/pipeline/inline_pipeline.h"
#include "stitch/records/merger_records.h"
#include "stitch/source/source.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/child_process.h"
#include "tests/test_process.h"

namespace stitch {
namespace {

using namespace std::chrono_literals;
using testing::Bin;

// A 200-frame strip with a gust at frame 90, run in process: what the mapper publishes on
// <agent>/SUBMAP, what the tracker publishes on <agent>/POSE, and the ground truth.
struct GustStrip {
  std::vector<stitch::submap_update_t> updates;
  std::vector<stitch::frame_pose_t> poses;
  Trajectory ground_truth;
};

GustStrip FlyGustStrip() {
  StitchConfig config;
  config.synthetic.flight.num_frames = 200;
  config.synthetic.flight.num_strips = 1;
  config.synthetic.flight.strip_length_m = 1.15 * 200;
  SourceSpec spec;
  spec.synthetic = config.synthetic;
  spec.failures = "90:10";
  FailureSchedule unused;
  auto sequence = OpenSource(spec, &unused);
  const Vocabulary vocabulary = LoadVocabulary(config);
  const InlineRun run = RunInline(*sequence, config.pipeline(), vocabulary, nullptr, /*keep_submap_updates=*/true);
  GustStrip strip{ToMessages(run.submap_updates), {}, sequence->ground_truth()};
  for (const InlineFrame& f : run.frames) {
    const TrackResult& r = f.result;
    if (r.state != TrackingState::kOk || !r.cam_from_submap) continue;
    strip.poses.push_back(FramePoseMessage(f.frame_index, f.t_ns, r.submap, *r.cam_from_submap, r.reference_keyframe,
                                           r.cam_from_reference));
  }
  return strip;
}

std::vector<stitch::submap_update_t> GustStripUpdates() {
  return FlyGustStrip().updates;
}

// The submap updates in a journal, as liblcm's own reader reads it (each update's checksum
// record not counted).
int64_t JournalRecords(const std::string& path) {
  if (!std::filesystem::exists(path)) return 0;
  lcm::LogFile log(path, "r");
  int64_t count = 0;
  while (log.good()) {
    const lcm::LogEvent* event = log.readNextEvent();
    if (!event) break;
    count += event->channel != kJournalChecksumChannel;
  }
  return count;
}

// keyframes_merged.tsv: keyframe id -> its merged map and pose (scale, rotation, translation).
std::map<int64_t, std::vector<double>> MergedKeyframes(const std::string& path) {
  std::map<int64_t, std::vector<double>> rows;
  for (const MergedKeyframeRecord& r : ReadMergedKeyframeRecords(path)) {
    const Sim3d& s = r.world_from_cam;
    rows[r.keyframe.value] = {static_cast<double>(r.component),
                              s.scale,
                              s.rotation.x(),
                              s.rotation.y(),
                              s.rotation.z(),
                              s.rotation.w(),
                              s.translation.x(),
                              s.translation.y(),
                              s.translation.z()};
  }
  return rows;
}

class MergerProcess {
 public:
  MergerProcess(const std::string& url, const std::string& state, const std::string& record, const std::string& log)
      : process_("merger", Bin("stitch-merger"), {"--lcm-url", url, "--state", state, "--record", record}, log) {
    // "listening on" comes once it has resumed from its journal, subscribed and set its stop
    // signals (a fixed wait let a SIGTERM on a loaded machine kill it before: exit 143).
    const auto deadline = std::chrono::steady_clock::now() + 60s;
    while (process_.LogTail(200).find("listening on ") == std::string::npos && !process_.Poll() &&
           std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(20ms);
    }
  }
  ChildProcess& process() { return process_; }

 private:
  ChildProcess process_;
};

void Publish(bus::Publisher* publisher, std::vector<stitch::submap_update_t>* messages, size_t from, size_t to) {
  for (size_t i = from; i < to; ++i) {
    publisher->Publish(bus::Channel("uav0", bus::kSubmap), &(*messages)[i]);
    std::this_thread::sleep_for(3ms);  // well inside the receive buffer
  }
}

bool WaitForJournal(const std::string& path, int64_t records, std::chrono::seconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (JournalRecords(path) < records) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(50ms);
  }
  return true;
}

TEST(MergerRestart, AMergerKilledHalfwayResumesFromItsJournalAndLosesNothing) {
  std::vector<stitch::submap_update_t> messages = GustStripUpdates();
  ASSERT_GT(messages.size(), 20u);
  testing::TempDir dir;
  const std::string url = bus::UnusedLocalUdpUrl();
  auto lcm = bus::OpenLcm(url);
  bus::Publisher publisher(lcm.get(), "uav0");
  const size_t half = messages.size() / 2;

  // A merger that runs through.
  {
    MergerProcess merger(url, dir / "state_through", dir / "through", dir / "through.log");
    Publish(&publisher, &messages, 0, messages.size());
    ASSERT_TRUE(WaitForJournal(dir / "state_through/submap_updates.lcmlog", messages.size(), 60s))
        << merger.process().LogTail(10);
    EXPECT_EQ(merger.process().Terminate(30s), 0) << merger.process().LogTail(10);
  }
  // One killed halfway, then restarted on the same state folder. Before the kill it also got
  // three GNSS fixes (too few to place a map: the merged maps stay as they were).
  const std::string journal = dir / "state/submap_updates.lcmlog";
  constexpr int kFixes = 3;
  {
    MergerProcess merger(url, dir / "state", dir / "first", dir / "first.log");
    Publish(&publisher, &messages, 0, half);
    for (int i = 0; i < kFixes; ++i) {
      stitch::gnss_fix_t fix{};
      fix.t_ns = 1'000'000'000LL + i * 200'000'000LL;
      fix.latitude_deg = 48.0;
      fix.longitude_deg = 11.0 + 1e-5 * i;
      fix.height_m = 600.0;
      fix.horizontal_accuracy_m = 2.0;
      fix.vertical_accuracy_m = 3.0;
      fix.fix_type = stitch::gnss_fix_t::FIX_3D;
      publisher.Publish(bus::Channel("uav0", bus::kGnss), &fix);
    }
    ASSERT_TRUE(WaitForJournal(journal, static_cast<int64_t>(half) + kFixes, 60s)) << merger.process().LogTail(10);
    EXPECT_EQ(merger.process().Terminate(0ms), 128 + SIGKILL);
  }
  {
    MergerProcess merger(url, dir / "state", dir / "resumed", dir / "resumed.log");
    Publish(&publisher, &messages, half, messages.size());
    ASSERT_TRUE(WaitForJournal(journal, static_cast<int64_t>(messages.size()) + kFixes, 60s))
        << merger.process().LogTail(10);
    EXPECT_EQ(merger.process().Terminate(30s), 0) << merger.process().LogTail(10);
    const std::string text = testing::ReadWholeFile(dir / "resumed.log");
    EXPECT_NE(text.find("resumed from"), std::string::npos) << text;
  }
  EXPECT_EQ(JournalRecords(journal), static_cast<int64_t>(messages.size()) + kFixes);
  // The fixes taken before the kill are still the merger's after it.
  EXPECT_EQ(ReadGnssCsv(dir / "resumed/gnss_received.csv").fixes.size(), static_cast<size_t>(kFixes));

  // The same merged map: every keyframe, at the same refined pose.
  const auto through = MergedKeyframes(dir / "through/keyframes_merged.tsv");
  const auto resumed = MergedKeyframes(dir / "resumed/keyframes_merged.tsv");
  ASSERT_GT(through.size(), 20u);
  EXPECT_EQ(resumed, through);
  // The journal is an LCM log: `stitch map` rebuilds the same merged map from it, offline.
  const testing::CommandResult rebuilt = testing::RunProgram({Bin("stitch"), "map", journal, "--out", dir / "rebuilt"});
  ASSERT_EQ(rebuilt.exit_code, 0) << rebuilt.output;
  EXPECT_EQ(MergedKeyframes(dir / "rebuilt/keyframes_merged.tsv"), through);
  EXPECT_EQ(ReadGnssCsv(dir / "rebuilt/gnss_received.csv").fixes.size(), static_cast<size_t>(kFixes));

  int merged = 0;
  for (const SubmapRecord& r : ReadSubmapRecords(dir / "resumed/submaps.tsv")) merged += r.component == 0;
  EXPECT_EQ(merged, 2) << "both submaps in merged map 0";
}

// The security issue's journal rows: a length field set to 0x7fffffff (every start of the merger
// crashed in liblcm's reader, and `stitch map` too) and 4 zeroed bytes mid-file (the restarted
// merger deleted everything after them). Each costs the record it hits and nothing else.
TEST(MergerRestart, ADamagedJournalCostsOnlyTheDamagedRecords) {
  std::vector<stitch::submap_update_t> messages = GustStripUpdates();
  ASSERT_GT(messages.size(), 20u);
  testing::TempDir dir;
  const std::string journal_path = dir / "state/submap_updates.lcmlog";
  std::vector<int64_t> offsets;
  {
    UpdateJournal journal(dir / "state", {"uav0/SUBMAP"});
    journal.Recover([](const stitch::submap_update_t&) {});
    for (stitch::submap_update_t& message : messages) {
      offsets.push_back(static_cast<int64_t>(std::filesystem::file_size(journal_path)));
      message.header.agent = "uav0";  // as the mapper's publisher sets it
      journal.Append(message);
    }
  }
  {
    std::fstream file(journal_path, std::ios::binary | std::ios::in | std::ios::out);
    file.seekp(offsets[messages.size() / 3] + 24);  // the data length
    file.write("\x7f\xff\xff\xff", 4);
    file.seekp(offsets[2 * messages.size() / 3]);  // the sync word
    file.write("\0\0\0\0", 4);
  }
  const int64_t kept = static_cast<int64_t>(messages.size()) - 2;

  // `stitch map` makes the map from every intact record, says what it lacks, and fails.
  std::filesystem::copy_file(journal_path, dir / "damaged.lcmlog");
  const testing::CommandResult map =
      testing::RunProgram({Bin("stitch"), "map", dir / "damaged.lcmlog", "--out", dir / "map"});
  EXPECT_EQ(map.exit_code, 3) << map.output;
  EXPECT_NE(map.output.find("2 damaged stretches"), std::string::npos) << map.output;
  EXPECT_NE(map.output.find("merged " + std::to_string(kept) + " submap updates"), std::string::npos) << map.output;
  EXPECT_FALSE(MergedKeyframes(dir / "map/keyframes_merged.tsv").empty());

  // The merger starts on it (no crash loop), keeps every intact record and sets the damage aside.
  const std::string url = bus::UnusedLocalUdpUrl();
  {
    MergerProcess merger(url, dir / "state", dir / "resumed", dir / "resumed.log");
    EXPECT_EQ(merger.process().Terminate(30s), 0) << merger.process().LogTail(10);
  }
  const std::string text = testing::ReadWholeFile(dir / "resumed.log");
  EXPECT_NE(text.find("resumed from " + journal_path + ": " + std::to_string(kept) + " submap updates"),
            std::string::npos)
      << text;
  EXPECT_TRUE(std::filesystem::exists(journal_path + ".damaged"));
  EXPECT_EQ(JournalRecords(journal_path), kept);  // liblcm's reader reads the mended journal through
}

// The ground's live outputs (issue #22): the merger writes its map and tables at every refinement
// and the per-frame trajectory of the pose stream during the flight, so a merger killed mid-flight
// leaves them on disk, readable, with the submaps merged so far.
TEST(MergerLiveOutputs, AMergerKilledMidFlightLeavesItsMapAndPerFrameTrajectoryOnDisk) {
  GustStrip strip = FlyGustStrip();
  size_t first_closed = 0;  // the last part of the update that closes the first submap
  while (first_closed < strip.updates.size() &&
         !(strip.updates[first_closed].closed &&
           strip.updates[first_closed].part == strip.updates[first_closed].num_parts - 1)) {
    ++first_closed;
  }
  ASSERT_LT(first_closed, strip.updates.size());
  testing::TempDir dir;
  const std::string url = bus::UnusedLocalUdpUrl();
  auto lcm = bus::OpenLcm(url);
  bus::Publisher publisher(lcm.get(), "uav0");
  const std::string out = dir / "ground";
  MergerProcess merger(url, dir / "state", out, dir / "merger.log");
  const auto wait_for = [&](const std::function<bool()>& done, const char* what) {
    const auto deadline = std::chrono::steady_clock::now() + 60s;
    while (!done()) {
      if (std::chrono::steady_clock::now() > deadline) {
        ADD_FAILURE() << "waited 60 s for " << what << "; " << merger.process().LogTail(10);
        return false;
      }
      std::this_thread::sleep_for(100ms);
    }
    return true;
  };
  const auto frames_on_disk = [&] {
    try {
      return std::filesystem::exists(out + "/trajectory.tum") ? Trajectory::ReadTum(out + "/trajectory.tum").size()
                                                              : size_t{0};
    } catch (const Error&) {
      return size_t{0};  // never: the file is replaced whole
    }
  };
  // Everything, the poses interleaved with the updates, all but the very end.
  const size_t updates_sent = strip.updates.size() - 2;
  size_t pose = 0;
  for (size_t i = 0; i < updates_sent; ++i) {
    publisher.Publish(bus::Channel("uav0", bus::kSubmap), &strip.updates[i]);
    for (size_t k = 0; k < 5 && pose < strip.poses.size(); ++k, ++pose) {
      publisher.Publish(bus::Channel("uav0", bus::kPose), &strip.poses[pose]);
    }
    std::this_thread::sleep_for(3ms);
    if (i == first_closed) {
      // The first submap closed: the refinement writes the map and its frames at once.
      ASSERT_TRUE(wait_for([&] { return std::filesystem::exists(out + "/map.ply") && frames_on_disk() > 0; },
                           "the first refinement's map and trajectory"));
    }
  }
  for (; pose < strip.poses.size(); ++pose) publisher.Publish(bus::Channel("uav0", bus::kPose), &strip.poses[pose]);
  // Both submaps merged on disk: most frames in the trajectory (written every 2 s).
  ASSERT_TRUE(wait_for([&] { return frames_on_disk() > strip.poses.size() * 3 / 4; }, "the frames of both submaps"));
  EXPECT_EQ(merger.process().Terminate(0ms), 128 + SIGKILL);

  const Trajectory trajectory = Trajectory::ReadTum(out + "/trajectory.tum");
  EXPECT_GT(trajectory.size(), strip.poses.size() * 3 / 4);
  const std::optional<TrajectoryErrors> errors = CompareTrajectories(trajectory.poses(), strip.ground_truth);
  ASSERT_TRUE(errors);
  EXPECT_LT(errors->ate_rmse_m, 1.0) << "the strip is 230 m; a submap placed wrongly is metres off";
  std::printf("the ground's trajectory.tum at the kill: %zu of %zu posed frames, ATE %.3f m\n", trajectory.size(),
              strip.poses.size(), errors->ate_rmse_m);
  EXPECT_GT(ReadPly(out + "/map.ply").size(), 1000u);
  int merged = 0;
  for (const SubmapRecord& r : ReadSubmapRecords(out + "/submaps.tsv")) merged += r.component == 0;
  EXPECT_GE(merged, 1);
  // keyframes_merged.tsv carries each keyframe's frame and time.
  const std::vector<MergedKeyframeRecord> keyframes = ReadMergedKeyframeRecords(out + "/keyframes_merged.tsv");
  ASSERT_FALSE(keyframes.empty());
  int timed = 0;
  for (const MergedKeyframeRecord& r : keyframes) {
    EXPECT_GE(r.frame_index, 0);
    timed += r.t_ns > 0;
  }
  EXPECT_GE(timed, static_cast<int>(keyframes.size()) - 1);
}

}  // namespace
}  // namespace stitch
