#pragma once
// A bounded multi-producer, multi-consumer queue for passing owned items between threads.
// When full, Push() either drops the oldest item (real-time input: the newest frame matters) or
// waits for room (work that must not be lost). Thread-safe.

#include <chrono>
#include <condition_variable>
#include <deque>
#include <mutex>
#include <optional>

namespace stitch {

template <class T>
class BoundedQueue {
 public:
  enum class WhenFull { kDropOldest, kWait };

  BoundedQueue(size_t capacity, WhenFull when_full) : capacity_(capacity), when_full_(when_full) {}

  // Adds an item. With kDropOldest, returns the item it dropped to make room, if any; with kWait,
  // blocks until there is room (returns nothing). Does nothing after Close().
  std::optional<T> Push(T item) {
    std::unique_lock<std::mutex> lock(mutex_);
    std::optional<T> dropped;
    if (closed_) return dropped;
    if (items_.size() >= capacity_) {
      if (when_full_ == WhenFull::kDropOldest) {
        dropped = std::move(items_.front());
        items_.pop_front();
      } else {
        not_full_.wait(lock, [&] { return items_.size() < capacity_ || closed_; });
        if (closed_) return dropped;
      }
    }
    items_.push_back(std::move(item));
    not_empty_.notify_one();
    return dropped;
  }

  // Waits up to `timeout` for an item; empty on timeout or when closed and drained.
  std::optional<T> Pop(std::chrono::milliseconds timeout) {
    std::unique_lock<std::mutex> lock(mutex_);
    if (!not_empty_.wait_for(lock, timeout, [&] { return !items_.empty() || closed_; })) return std::nullopt;
    if (items_.empty()) return std::nullopt;
    T item = std::move(items_.front());
    items_.pop_front();
    not_full_.notify_one();
    return item;
  }

  void Close() {
    std::lock_guard<std::mutex> lock(mutex_);
    closed_ = true;
    not_empty_.notify_all();
    not_full_.notify_all();
  }
  bool closed() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return closed_;
  }
  size_t size() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return items_.size();
  }
  // How many queued items satisfy `predicate` (called under the queue's lock).
  template <class Predicate>
  size_t CountIf(const Predicate& predicate) const {
    std::lock_guard<std::mutex> lock(mutex_);
    size_t count = 0;
    for (const T& item : items_) count += predicate(item) ? 1 : 0;
    return count;
  }

 private:
  const size_t capacity_;
  const WhenFull when_full_;
  mutable std::mutex mutex_;
  std::condition_variable not_empty_, not_full_;
  std::deque<T> items_;
  bool closed_ = false;
};

}  // namespace stitch
