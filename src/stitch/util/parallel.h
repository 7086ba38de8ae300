#pragma once
// Runs the items of a small batch on the calling thread and up to `threads - 1` helper threads
// that stay up between batches (per-frame work cannot pay for starting threads each time).
// Items are taken in order as threads come free. One batch at a time; Run() is not reentrant.

#include <atomic>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace stitch {

class ParallelRunner {
 public:
  // threads <= 1: every batch runs on the calling thread alone.
  explicit ParallelRunner(int threads);
  ~ParallelRunner();
  ParallelRunner(const ParallelRunner&) = delete;
  ParallelRunner& operator=(const ParallelRunner&) = delete;

  // Calls item(i) once for every i in [0, count), returning when all have finished. Items must
  // not throw.
  void Run(int count, const std::function<void(int)>& item);
  int threads() const { return static_cast<int>(helpers_.size()) + 1; }

 private:
  void Help();
  void TakeItems();

  std::vector<std::thread> helpers_;
  std::mutex mutex_;
  std::condition_variable wake_, done_;
  const std::function<void(int)>* item_ = nullptr;
  int count_ = 0;
  std::atomic<int> next_{0};
  int batch_ = 0;  // number of the current batch; helpers wait for a new one
  int helpers_busy_ = 0;
  bool stop_ = false;
};

}  // namespace stitch
