// A run's channels can be recorded with lcm-logger (or `stitch record`) and replayed with
// lcm-logplayer.

#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "services/common/bus.h"
#include "stitch/frame_t.hpp"
#include "stitch/link_status_t.hpp"
#include "stitch/service_status_t.hpp"
#include "stitch/submap_request_t.hpp"
#include "stitch/submap_update_t.hpp"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/child_process.h"
#include "stitch/util/ids.h"
#include "tests/test_process.h"

namespace stitch {
namespace {

using namespace std::chrono_literals;
using testing::Bin;
using testing::RunProgram;

TEST(LcmLog, LoggerRecordsFramesAndLogplayerReplaysThem) {
  if (!testing::OnPath("lcm-logger") || !testing::OnPath("lcm-logplayer")) {
    GTEST_SKIP() << "lcm-logger / lcm-logplayer not installed (Debian package liblcm-bin)";
  }
  testing::TempDir dir;
  const std::vector<int> ports = bus::UnusedUdpPorts(2);  // record, replay
  const std::string record_url = bus::LocalUdpUrl(ports[0]);
  const std::string log = dir / "run.lcmlog";
  const std::string logger = "/usr/bin/lcm-logger";
  // Record while ingest plays 10 frames in real time (no tracker: it does not wait for one).
  std::thread recorder([&] { RunProgram({logger, "--lcm-url=" + record_url, "-f", log}, 30, 4, SIGINT); });
  std::this_thread::sleep_for(1s);
  const auto ingest = RunProgram({Bin("stitch-ingest"), "--lcm-url", record_url, "--config",
                                  std::string(STITCH_SOURCE_DIR) + "/tests/short_flight.yaml", "--pacing", "realtime",
                                  "--max-frames", "10", "--encoding", "jpeg", "--set", "ingest.wait_for_tracker_s=0"},
                                 30);
  recorder.join();
  ASSERT_EQ(ingest.exit_code, 0) << ingest.output;
  ASSERT_TRUE(std::filesystem::exists(log));
  ASSERT_GT(std::filesystem::file_size(log), 10000u);
  int frames_recorded = 0;
  {
    lcm::LogFile file(log, "r");
    ASSERT_TRUE(file.good());
    while (const lcm::LogEvent* event = file.readNextEvent()) frames_recorded += event->channel == "uav0/FRAME";
  }
  EXPECT_EQ(frames_recorded, 10);

  // Replay onto another bus, at the recorded rate (a loaded machine's receiver falls behind
  // faster playback and UDP drops what it cannot hold), and count the frames that come back.
  const std::string replay_url = bus::LocalUdpUrl(ports[1]);
  auto lcm = bus::OpenLcm(replay_url);
  std::atomic<int> frames{0};
  bus::Subscriber subscriber(lcm.get());
  subscriber.Subscribe<stitch::frame_t>(bus::Channel("uav0", bus::kFrame),
                                        [&](std::unique_ptr<stitch::frame_t>, const std::string&) { ++frames; });
  bus::Dispatcher dispatcher(lcm.get());
  dispatcher.Start();
  const auto play = RunProgram({"/usr/bin/lcm-logplayer", "--lcm-url=" + replay_url, log}, 30);
  for (auto deadline = std::chrono::steady_clock::now() + 10s;
       frames.load() < frames_recorded && std::chrono::steady_clock::now() < deadline;) {
    std::this_thread::sleep_for(50ms);
  }
  dispatcher.Stop();
  EXPECT_EQ(play.exit_code, 0) << play.output;
  EXPECT_EQ(frames.load(), frames_recorded);
}

// stitch record keeps the channels that cross to the ground, and says what it missed: the gaps
// in each sender's sequence numbers (a recording that lost messages said nothing).
TEST(LcmLog, StitchRecordKeepsWhatCrossesToTheGroundAndNoImages) {
  testing::TempDir dir;
  const std::string url = bus::UnusedLocalUdpUrl();
  const std::string log = dir / "flight.lcmlog";
  testing::CommandResult recorded;
  std::thread recorder([&] { recorded = RunProgram({Bin("stitch"), "record", "--lcm-url", url, log}, 30, 3, SIGINT); });
  std::this_thread::sleep_for(1s);
  auto lcm = bus::OpenLcm(url);
  bus::Publisher uav0(lcm.get(), "uav0"), uav1(lcm.get(), "uav1");
  for (int i = 0; i < 5; ++i) {
    stitch::submap_update_t update{};
    update.submap_id = MakeSubmapId(0, 1).value;
    update.revision = i;
    update.num_parts = 1;
    uav0.Publish(bus::Channel("uav0", bus::kSubmap), &update);
    stitch::frame_t frame{};
    frame.frame_index = i;
    uav0.Publish(bus::Channel("uav0", bus::kFrame), &frame);
    uav1.Publish(bus::Channel("uav1", bus::kSubmap), &update);  // not an aircraft we record
    std::this_thread::sleep_for(20ms);
  }
  // A sender whose messages 2 and 3 never reached the bus.
  for (int64_t seq : {0, 1, 4}) {
    stitch::service_status_t status{};
    status.header.agent = "uav0";
    status.header.sender_session = 99;
    status.header.seq = seq;
    lcm->publish(bus::Channel("uav0", bus::kService), &status);
  }
  recorder.join();
  EXPECT_NE(recorded.output.find("8 messages on 2 channels"), std::string::npos) << recorded.output;
  EXPECT_NE(recorded.output.find("missed 2 messages their senders numbered (uav0/SERVICE 2)"), std::string::npos)
      << recorded.output;
  std::map<std::string, int> channels;
  lcm::LogFile file(log, "r");
  ASSERT_TRUE(file.good());
  while (const lcm::LogEvent* event = file.readNextEvent()) ++channels[event->channel];
  EXPECT_EQ(channels["uav0/SUBMAP"], 5);
  EXPECT_EQ(channels["uav0/SERVICE"], 3);
  EXPECT_EQ(channels.count("uav0/FRAME"), 0u);
  EXPECT_EQ(channels.count("uav1/SUBMAP"), 0u);
  // It does not overwrite a recording.
  const auto again = RunProgram({Bin("stitch"), "record", "--lcm-url", url, log}, 10);
  EXPECT_EQ(again.exit_code, 1);
  EXPECT_NE(again.output.find("exists"), std::string::npos) << again.output;
}

// Two recorders beside a run on a loaded machine, on the address form the docs showed (no receive
// buffer named): a recorder lost submap messages, and a run stalled on a mapper that missed a
// keyframe. Every bus now gets a 2 MB buffer; both recordings are whole and the run ends.
TEST(LcmLog, TwoRecordersBesideARunOnABusyMachineMissNothing) {
  testing::TempDir dir;
  const std::string url = "udpm://239.255.76.67:" + std::to_string(bus::UnusedUdpPort()) + "?ttl=0";
  ChildProcess features("recorder", Bin("stitch"), {"record", "--lcm-url", url, dir / "features.lcmlog"},
                        dir / "features.log");
  ChildProcess everything("recorder-all", Bin("stitch"), {"record", "--all", "--lcm-url", url, dir / "all.lcmlog"},
                          dir / "all.log");
  std::this_thread::sleep_for(1s);
  testing::CommandResult run;
  {
    const testing::BusyLoops loaded(2);
    run = RunProgram({Bin("stitch"), "run", "--lcm-url", url, "--config", testing::ShortFlightConfig(), "--failures",
                      "none", "--out", dir / "run", "--quiet"},
                     300);
  }
  std::this_thread::sleep_for(500ms);  // the recorders write the last messages
  features.Terminate(std::chrono::seconds(10));
  everything.Terminate(std::chrono::seconds(10));
  ASSERT_EQ(run.exit_code, 0) << run.output;
  for (const std::string& log : {dir / "features.log", dir / "all.log"}) {
    std::stringstream said;
    said << std::ifstream(log).rdbuf();
    EXPECT_NE(said.str().find("missed 0 "), std::string::npos) << log << ":\n" << said.str();
  }
  EXPECT_GE(testing::ReadJson(dir / "run/report.json")["frames_localized"].get<int>(), 50) << run.output;
}

// What lcm-spy shows of a run: every channel a run publishes decodes with stitch's Java types,
// by fingerprint as lcm-spy finds them (`stitch spy --log` on a recording of the whole bus).
TEST(LcmLog, StitchSpyDecodesEveryChannelOfARecordedRun) {
  if (!testing::OnPath("lcm-logger")) GTEST_SKIP() << "lcm-logger not installed (Debian package liblcm-bin)";
  if (!std::filesystem::exists(std::filesystem::path(Bin("stitch")).parent_path() / ".." / "share" / "java" /
                               "stitch-lcmtypes.jar")) {
    GTEST_SKIP() << "stitch was built without its Java types (Debian packages default-jdk-headless, liblcm-java)";
  }
  testing::TempDir dir;
  const std::string url = bus::UnusedLocalUdpUrl();
  const std::string log = dir / "run.lcmlog";
  ChildProcess recorder("recorder", Bin("stitch"), {"record", "--all", "--lcm-url", url, log}, dir / "record.log");
  std::this_thread::sleep_for(1s);
  const auto run = RunProgram(
      {Bin("stitch"), "run", "--lcm-url", url, "--config", std::string(STITCH_SOURCE_DIR) + "/tests/short_flight.yaml",
       "--failures", "none", "--out", dir / "run", "--quiet"},
      150);
  {
    // The two channels a run on one bus does not use: the link bridges' status, and a request
    // for what the link lost (the merger asks only when something is missing).
    auto lcm = bus::OpenLcm(url);
    bus::Publisher publisher(lcm.get(), "uav0");
    stitch::link_status_t status{};
    publisher.Publish(bus::Channel("uav0", bus::kLinkStatus), &status);
    stitch::submap_request_t request{};
    request.submap_id = MakeSubmapId(0, 1).value;
    publisher.Publish(bus::Channel("uav0", bus::kSubmapRequest), &request);
  }
  std::this_thread::sleep_for(500ms);  // the logger writes the last messages
  recorder.Terminate(std::chrono::seconds(10));
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const auto spy = RunProgram({Bin("stitch"), "spy", "--log", log}, 60);
  ASSERT_EQ(spy.exit_code, 0) << spy.output;
  // channel, type, messages, decoded, undecodable
  std::map<std::string, std::string> types;
  std::istringstream lines(spy.output);
  for (std::string line; std::getline(lines, line);) {
    std::istringstream fields(line);
    std::string channel, type;
    long long messages = -1, decoded = -1, undecodable = -1;
    if (!(fields >> channel >> type >> messages >> decoded >> undecodable)) continue;
    types[channel] = type;
    EXPECT_GT(messages, 0) << line;
    EXPECT_EQ(decoded, messages) << line;
    EXPECT_EQ(undecodable, 0) << line;
  }
  const std::map<std::string, std::string> expected = {{"uav0/FRAME", "stitch.frame_t"},
                                                       {"uav0/FRAME_ACK", "stitch.frame_ack_t"},
                                                       {"uav0/SEQUENCE", "stitch.sequence_info_t"},
                                                       {"uav0/TRACKING_STATUS", "stitch.tracking_status_t"},
                                                       {"uav0/POSE", "stitch.frame_pose_t"},
                                                       {"uav0/MAP_CLOUD", "stitch.map_cloud_t"},
                                                       {"uav0/KEYFRAME", "stitch.keyframe_t"},
                                                       {"uav0/LOCAL_MAP", "stitch.local_map_update_t"},
                                                       {"uav0/SUBMAP", "stitch.submap_update_t"},
                                                       {"uav0/GLOBAL_MAP", "stitch.global_map_t"},
                                                       {"uav0/SERVICE", "stitch.service_status_t"},
                                                       {"uav0/LINK_STATUS", "stitch.link_status_t"},
                                                       {"uav0/SUBMAP_REQUEST", "stitch.submap_request_t"}};
  for (const auto& [channel, type] : expected) EXPECT_EQ(types[channel], type) << channel << "\n" << spy.output;
  // The same log decoded in Lua with the generated Lua types (Debian's liblcm-lua).
  if (testing::OnPath("lua5.2") && std::filesystem::exists("/usr/lib/lua/5.2/lcm.so")) {
    const std::string lua_path =
        (std::filesystem::path(Bin("stitch")).parent_path() / ".." / "share" / "lua").lexically_normal().string();
    const auto lua = RunProgram({"/usr/bin/env", "LUA_PATH=" + lua_path + "/?.lua;;", "lua5.2",
                                 std::string(STITCH_SOURCE_DIR) + "/tools/spy/decode_log.lua", log},
                                60);
    ASSERT_EQ(lua.exit_code, 0) << lua.output;
    for (const auto& [channel, type] : expected) {
      // "channel<TAB>type<TAB>messages<TAB>decoded<TAB>0<TAB>bytes<TAB>bytes/s": the Java line, decoded
      // and counted the same.
      const size_t java = spy.output.find(channel + "\t" + type + "\t");
      ASSERT_NE(java, std::string::npos) << channel;
      const std::string line = spy.output.substr(java, spy.output.find('\n', java) - java);
      EXPECT_NE(lua.output.find(line), std::string::npos) << line << "\nnot in Lua's\n" << lua.output.substr(0, 2000);
    }
  } else {
    std::printf("lua5.2 or liblcm-lua not installed: the Lua decoding is not checked\n");
  }
  // A file that is no log is said to be none.
  std::ofstream(dir / "garbage.lcmlog") << "not an LCM log at all";
  const auto garbage = RunProgram({Bin("stitch"), "spy", "--log", dir / "garbage.lcmlog"}, 60);
  EXPECT_NE(garbage.exit_code, 0);
  EXPECT_NE(garbage.output.find("not an LCM log"), std::string::npos) << garbage.output;
  // Without a display the live view says what to do instead.
  const auto live = RunProgram({"/usr/bin/env", "-u", "DISPLAY", "-u", "WAYLAND_DISPLAY", Bin("stitch"), "spy"}, 30);
  EXPECT_NE(live.exit_code, 0);
  EXPECT_NE(live.output.find("--log FILE"), std::string::npos) << live.output;
}

}  // namespace
}  // namespace stitch
