#include "stitch/util/parallel.h"

#include <gtest/gtest.h>

#include <atomic>
#include <set>

namespace stitch {
namespace {

TEST(ParallelRunner, RunsEveryItemOnceInEveryBatch) {
  for (int threads : {1, 2, 4}) {
    ParallelRunner runner(threads);
    EXPECT_EQ(runner.threads(), threads);
    for (int batch = 0; batch < 200; ++batch) {
      const int count = batch % 9;
      std::vector<std::atomic<int>> calls(count);
      runner.Run(count, [&](int i) { ++calls[i]; });
      for (int i = 0; i < count; ++i) ASSERT_EQ(calls[i].load(), 1) << "threads " << threads << " batch " << batch;
    }
  }
}

TEST(ParallelRunner, UsesTheHelperThreads) {
  ParallelRunner runner(2);
  std::mutex mutex;
  std::set<std::thread::id> seen;
  for (int batch = 0; batch < 50 && seen.size() < 2; ++batch) {
    runner.Run(8, [&](int) {
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
      std::lock_guard<std::mutex> lock(mutex);
      seen.insert(std::this_thread::get_id());
    });
  }
  EXPECT_EQ(seen.size(), 2u);
}

}  // namespace
}  // namespace stitch

#include "stitch/util/worker_thread.h"

namespace stitch {
namespace {

TEST(WorkerThread, RunsTasksInOrderOffTheCallingThreadAndDrains) {
  std::vector<int> order;
  std::set<std::thread::id> threads;
  {
    WorkerThread worker;
    for (int i = 0; i < 100; ++i) {
      worker.Submit([&, i] {
        order.push_back(i);
        threads.insert(std::this_thread::get_id());
      });
    }
    worker.Drain();
    EXPECT_EQ(order.size(), 100u);
    worker.Submit([&] {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
      order.push_back(100);
    });
  }  // the destructor runs what is queued
  ASSERT_EQ(order.size(), 101u);
  for (int i = 0; i <= 100; ++i) EXPECT_EQ(order[i], i);
  EXPECT_EQ(threads.size(), 1u);
  EXPECT_EQ(threads.count(std::this_thread::get_id()), 0u);
}

}  // namespace
}  // namespace stitch
