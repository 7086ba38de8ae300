#include "stitch/source/read_ahead.h"

#include <condition_variable>
#include <deque>
#include <exception>
#include <mutex>
#include <thread>
#include <utility>

namespace stitch {
namespace {

class ReadAheadSequence : public ImageSequence {
 public:
  ReadAheadSequence(std::unique_ptr<ImageSequence> inner, int frames)
      : inner_(std::move(inner)),
        frames_(static_cast<size_t>(frames)),
        description_(inner_->description()),
        size_(inner_->size()),
        camera_(inner_->camera()),
        fps_(inner_->nominal_fps()),
        ground_truth_(inner_->ground_truth()) {
    reader_ = std::thread([this] { Read(); });
  }
  ~ReadAheadSequence() override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stopping_ = true;
    }
    space_.notify_all();
    reader_.join();
  }

  // What the source says of itself, taken before its reader started: only the reader calls into
  // the source after that, but for image_path (a file list fixed when the source opened).
  std::string description() const override { return description_; }
  int size() const override { return size_; }
  const Camera& camera() const override { return camera_; }
  double nominal_fps() const override { return fps_; }
  const Trajectory& ground_truth() const override { return ground_truth_; }
  std::string image_path(int index) const override { return inner_->image_path(index); }

  bool Next(SequenceFrame* frame) override {
    std::unique_lock<std::mutex> lock(mutex_);
    ready_.wait(lock, [&] { return !queue_.empty() || ended_; });
    if (queue_.empty()) {
      if (error_) std::rethrow_exception(std::exchange(error_, nullptr));
      return false;
    }
    *frame = std::move(queue_.front());
    queue_.pop_front();
    space_.notify_one();
    return true;
  }

 private:
  void Read() {
    for (;;) {
      {
        std::unique_lock<std::mutex> lock(mutex_);
        space_.wait(lock, [&] { return stopping_ || queue_.size() < frames_; });
        if (stopping_) return;
      }
      SequenceFrame frame;
      bool more = false;
      std::exception_ptr error;
      try {
        more = inner_->Next(&frame);
      } catch (...) {
        error = std::current_exception();
      }
      std::lock_guard<std::mutex> lock(mutex_);
      if (error || !more) {
        error_ = error;
        ended_ = true;
        ready_.notify_all();
        return;
      }
      queue_.push_back(std::move(frame));
      ready_.notify_one();
    }
  }

  const std::unique_ptr<ImageSequence> inner_;
  const size_t frames_;
  const std::string description_;
  const int size_;
  const Camera camera_;
  const double fps_;
  const Trajectory ground_truth_;

  std::mutex mutex_;
  std::condition_variable ready_, space_;  // a frame was read or the source ended; room to read one
  std::deque<SequenceFrame> queue_;
  bool ended_ = false, stopping_ = false;
  std::exception_ptr error_;
  std::thread reader_;  // last: it starts once everything above stands
};

}  // namespace

std::unique_ptr<ImageSequence> ReadAhead(std::unique_ptr<ImageSequence> inner, int frames) {
  if (!inner || frames <= 0 || inner->live()) return inner;
  return std::make_unique<ReadAheadSequence>(std::move(inner), frames);
}

}  // namespace stitch
