#include "stitch/util/bounded_queue.h"

#include <thread>

#include <gtest/gtest.h>

namespace stitch {
namespace {

using namespace std::chrono_literals;

TEST(BoundedQueue, DropOldestKeepsTheNewest) {
  BoundedQueue<int> queue(2, BoundedQueue<int>::WhenFull::kDropOldest);
  EXPECT_FALSE(queue.Push(1));
  EXPECT_FALSE(queue.Push(2));
  const auto dropped = queue.Push(3);
  ASSERT_TRUE(dropped);
  EXPECT_EQ(*dropped, 1);
  EXPECT_EQ(*queue.Pop(0ms), 2);
  EXPECT_EQ(*queue.Pop(0ms), 3);
  EXPECT_FALSE(queue.Pop(1ms));
}

TEST(BoundedQueue, WaitBlocksUntilThereIsRoom) {
  BoundedQueue<int> queue(1, BoundedQueue<int>::WhenFull::kWait);
  queue.Push(1);
  std::thread producer([&] { queue.Push(2); });
  std::this_thread::sleep_for(20ms);
  EXPECT_EQ(queue.size(), 1u);
  EXPECT_EQ(*queue.Pop(100ms), 1);
  producer.join();
  EXPECT_EQ(*queue.Pop(100ms), 2);
}

TEST(BoundedQueue, CloseWakesWaitersAndDrains) {
  BoundedQueue<int> queue(4, BoundedQueue<int>::WhenFull::kWait);
  queue.Push(5);
  queue.Close();
  EXPECT_EQ(*queue.Pop(10ms), 5);
  EXPECT_FALSE(queue.Pop(1000ms));  // returns at once: closed and empty
  queue.Push(6);
  EXPECT_EQ(queue.size(), 0u);
}

}  // namespace
}  // namespace stitch
