#include "stitch/tracking/keyframe_bow.h"

namespace stitch {

KeyframeBowWorker::KeyframeBowWorker(const Vocabulary* vocabulary)
    : vocabulary_(vocabulary), worker_(std::make_unique<WorkerThread>()) {}

KeyframeBowWorker::~KeyframeBowWorker() {
  worker_.reset();
}

void KeyframeBowWorker::Submit(KeyframeId keyframe, cv::Mat descriptors) {
  worker_->Submit([this, keyframe, descriptors = std::move(descriptors)] {
    Finished finished{keyframe, {}, {}};
    finished.bow = vocabulary_->Transform(descriptors, &finished.features);
    std::lock_guard<std::mutex> lock(mutex_);
    finished_.push_back(std::move(finished));
  });
}

std::vector<KeyframeBowWorker::Finished> KeyframeBowWorker::Take(bool wait) {
  if (wait) worker_->Drain();
  std::vector<Finished> finished;
  std::lock_guard<std::mutex> lock(mutex_);
  finished.swap(finished_);
  return finished;
}

}  // namespace stitch
