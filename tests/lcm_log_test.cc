// A run's channels can be recorded with lcm-logger (or `stitch record`) and replayed with
// lcm-logplayer.

#include <unistd.h>

#include <filesystem>
#include <map>
#include <thread>

#include <gtest/gtest.h>

#include "services/common/bus.h"
#include "stitch/frame_t.hpp"
#include "stitch/submap_update_t.hpp"
#include "stitch/testing/temp_dir.h"
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
  const int port = 7600 + getpid() % 90;
  const std::string record_url = bus::LocalUdpUrl(port);
  const std::string log = dir / "run.lcmlog";
  const std::string logger = "/usr/bin/lcm-logger";
  // Record while ingest plays 10 frames in real time (no tracker needed).
  std::thread recorder([&] { RunProgram({logger, "--lcm-url=" + record_url, "-f", log}, 30, 4, SIGINT); });
  std::this_thread::sleep_for(1s);
  const auto ingest = RunProgram({Bin("stitch-ingest"), "--lcm-url", record_url, "--config",
                                  std::string(STITCH_SOURCE_DIR) + "/tests/short_flight.yaml", "--pacing", "realtime",
                                  "--max-frames", "10", "--encoding", "jpeg"},
                                 30);
  recorder.join();
  ASSERT_EQ(ingest.exit_code, 0) << ingest.output;
  ASSERT_TRUE(std::filesystem::exists(log));
  ASSERT_GT(std::filesystem::file_size(log), 10000u);

  // Replay onto another bus and count the frames that come back.
  const std::string replay_url = bus::LocalUdpUrl(port + 100);
  auto lcm = bus::OpenLcm(replay_url);
  std::atomic<int> frames{0};
  bus::Subscriber subscriber(lcm.get());
  subscriber.Subscribe<stitch::frame_t>(bus::Channel("uav0", bus::kFrame),
                                        [&](std::unique_ptr<stitch::frame_t>, const std::string&) { ++frames; });
  bus::Dispatcher dispatcher(lcm.get());
  dispatcher.Start();
  const auto play = RunProgram({"/usr/bin/lcm-logplayer", "--lcm-url=" + replay_url, "--speed=4", log}, 30);
  std::this_thread::sleep_for(300ms);
  dispatcher.Stop();
  EXPECT_EQ(play.exit_code, 0) << play.output;
  EXPECT_EQ(frames.load(), 10);
}

TEST(LcmLog, StitchRecordKeepsWhatCrossesToTheGroundAndNoImages) {
  if (!testing::OnPath("lcm-logger")) GTEST_SKIP() << "lcm-logger not installed (Debian package liblcm-bin)";
  testing::TempDir dir;
  const std::string url = bus::LocalUdpUrl(7500 + getpid() % 90);
  const std::string log = dir / "flight.lcmlog";
  std::thread recorder([&] { RunProgram({Bin("stitch"), "record", "--lcm-url", url, log}, 30, 3, SIGINT); });
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
  recorder.join();
  std::map<std::string, int> channels;
  lcm::LogFile file(log, "r");
  ASSERT_TRUE(file.good());
  while (const lcm::LogEvent* event = file.readNextEvent()) ++channels[event->channel];
  EXPECT_EQ(channels["uav0/SUBMAP"], 5);
  EXPECT_EQ(channels.count("uav0/FRAME"), 0u);
  EXPECT_EQ(channels.count("uav1/SUBMAP"), 0u);
  // It does not overwrite a recording.
  const auto again = RunProgram({Bin("stitch"), "record", "--lcm-url", url, log}, 10);
  EXPECT_EQ(again.exit_code, 1);
  EXPECT_NE(again.output.find("exists"), std::string::npos) << again.output;
}

}  // namespace
}  // namespace stitch
