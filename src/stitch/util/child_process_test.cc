#include "stitch/util/child_process.h"

#include <chrono>
#include <thread>

#include <gtest/gtest.h>

#include "stitch/testing/temp_dir.h"

namespace stitch {
namespace {

// The quality gate's CPU figure: what the child and the processes it waited for spent.
TEST(ChildProcess, CountsTheCpuOfTheChildAndWhatItWaitedFor) {
  testing::TempDir dir;
  // A shell that runs a second shell spinning for a second, and waits for it. (On a loaded
  // machine the spinning gets a fraction of a core: 0.17 s of a half-second spin beside a build.)
  ChildProcess busy("busy", "/bin/sh",
                    {"-c", "sh -c 'end=$(($(date +%s%N) + 1000000000)); while [ $(date +%s%N) -lt $end ]; do :; done'"},
                    dir / "busy.log");
  std::optional<int> status;
  for (int i = 0; i < 200 && !(status = busy.Poll()); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  ASSERT_EQ(status, 0);
  EXPECT_GT(busy.cpu_seconds(), 0.15);
  ChildProcess idle("idle", "/bin/sh", {"-c", "sleep 0.5"}, dir / "idle.log");
  for (int i = 0; i < 200 && !(status = idle.Poll()); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  ASSERT_EQ(status, 0);
  EXPECT_LT(idle.cpu_seconds(), 0.05) << "sleeping costs no CPU";
}

}  // namespace
}  // namespace stitch
