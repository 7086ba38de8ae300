#include "stitch/util/parallel.h"

namespace stitch {

ParallelRunner::ParallelRunner(int threads) {
  for (int i = 1; i < threads; ++i) helpers_.emplace_back([this] { Help(); });
}

ParallelRunner::~ParallelRunner() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  for (auto& helper : helpers_) helper.join();
}

void ParallelRunner::TakeItems() {
  for (int i = next_.fetch_add(1); i < count_; i = next_.fetch_add(1)) (*item_)(i);
}

void ParallelRunner::Run(int count, const std::function<void(int)>& item) {
  if (helpers_.empty() || count <= 1) {
    for (int i = 0; i < count; ++i) item(i);
    return;
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    item_ = &item;
    count_ = count;
    next_ = 0;
    helpers_busy_ = static_cast<int>(helpers_.size());
    ++batch_;
  }
  wake_.notify_all();
  TakeItems();
  std::unique_lock<std::mutex> lock(mutex_);
  done_.wait(lock, [&] { return helpers_busy_ == 0; });
  item_ = nullptr;
}

void ParallelRunner::Help() {
  int seen = 0;
  std::unique_lock<std::mutex> lock(mutex_);
  while (true) {
    wake_.wait(lock, [&] { return stop_ || batch_ != seen; });
    if (stop_) return;
    seen = batch_;
    lock.unlock();
    TakeItems();
    lock.lock();
    if (--helpers_busy_ == 0) done_.notify_one();
  }
}

}  // namespace stitch
