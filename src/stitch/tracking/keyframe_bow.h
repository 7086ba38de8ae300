#pragma once
// New keyframes' bags of words, which only relocalization needs (the mapper computes its own),
// computed on a background thread so the frame loop does not wait for them. The owner takes the
// finished ones at a time of its choosing (Take); the worker touches nothing of the owner's.
// Submit and Take from one thread; the worker is internal.

#include <memory>
#include <mutex>
#include <vector>

#include <opencv2/core.hpp>

#include "stitch/features/bow.h"
#include "stitch/features/vocabulary.h"
#include "stitch/util/ids.h"
#include "stitch/util/worker_thread.h"

namespace stitch {

class KeyframeBowWorker {
 public:
  struct Finished {
    KeyframeId keyframe;
    BowVector bow;
    FeatureVector features;
  };

  // `vocabulary` must outlive the worker.
  explicit KeyframeBowWorker(const Vocabulary* vocabulary);
  ~KeyframeBowWorker();

  // Computes the bag of words of `keyframe`'s descriptors in the background.
  void Submit(KeyframeId keyframe, cv::Mat descriptors);
  // What has finished since the last call, in submission order; `wait`: everything submitted.
  std::vector<Finished> Take(bool wait);

 private:
  const Vocabulary* vocabulary_;
  std::mutex mutex_;
  std::vector<Finished> finished_;
  std::unique_ptr<WorkerThread> worker_;  // last: stopped first, while what its tasks use exists
};

}  // namespace stitch
