#include "stitch/util/child_process.h"

#include <fcntl.h>
#include <pthread.h>
#include <sys/wait.h>
#include <unistd.h>
#include <atomic>
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

// A library's fork handler (PROJ registers one that closes its database) allocates in the child;
// where another thread of the launcher held the allocator's lock at the fork, the child waited for
// it forever and the service never started (stop 64's CI, under AddressSanitizer). The launcher's
// children run no fork handlers.
std::atomic<int> fork_handler_pipe{-1};  // where the handler below says that it ran

TEST(ChildProcess, RunsNoForkHandlerOfTheLaunchersLibraries) {
  testing::TempDir dir;
  int ran[2];
  ASSERT_EQ(pipe2(ran, O_NONBLOCK | O_CLOEXEC), 0);
  fork_handler_pipe = ran[1];
  static std::once_flag registered;
  std::call_once(registered, [] {
    pthread_atfork(nullptr, nullptr, [] {
      const int fd = fork_handler_pipe.load();
      if (fd >= 0) (void)!write(fd, "x", 1);
    });
  });
  // The handler runs in a plain fork's child: this test can see it.
  const pid_t plain = fork();
  if (plain == 0) _exit(0);
  ASSERT_GT(plain, 0);
  ASSERT_EQ(waitpid(plain, nullptr, 0), plain);
  char said = 0;
  EXPECT_EQ(read(ran[0], &said, 1), 1) << "a plain fork runs the handler";

  ChildProcess child("true", "/bin/true", {}, dir / "true.log");
  std::optional<int> status;
  for (int i = 0; i < 200 && !(status = child.Poll()); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_EQ(status, 0);
  EXPECT_EQ(read(ran[0], &said, 1), -1) << "the launcher's child ran a fork handler";
  fork_handler_pipe = -1;
  close(ran[0]);
  close(ran[1]);
}

}  // namespace
}  // namespace stitch
