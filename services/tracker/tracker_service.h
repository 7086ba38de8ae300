#pragma once
// The tracker service: receives frames on <agent>/FRAME, tracks each with FrameTracker in its
// own worker thread, and publishes a tracking_status_t per frame and a frame_ack_t (lockstep
// pacing). Frames that arrive twice are acknowledged again but tracked once; frames that arrive
// after a newer one, or that wait while the queue is full (real-time), are reported as dropped.
// Writes one line per frame to `record_path` (frames.tsv) when given.

#include <atomic>
#include <fstream>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "services/common/bus.h"
#include "services/common/service.h"
#include "services/tracker/frame_tracker.h"
#include "services/tracker/tracker_options.h"
#include "stitch/frame_t.hpp"
#include "stitch/util/bounded_queue.h"

namespace stitch {

class TrackerService {
 public:
  // Subscribes at once: construct before the Dispatcher starts.
  TrackerService(lcm::LCM* lcm, bus::Publisher* publisher, TrackerOptions options, std::string record_path);
  ~TrackerService();

  void Start();
  // Tracks what is queued, writes the record, stops the worker.
  void Stop();

  int64_t frames_received() const { return received_.load(); }
  int64_t frames_tracked() const { return tracked_.load(); }
  int highest_processed() const { return highest_processed_.load(); }

 private:
  void OnFrame(std::unique_ptr<stitch::frame_t> frame);
  void Work();
  void Process(const stitch::frame_t& frame);
  void Report(const stitch::frame_t& frame, const TrackResult& result, float tracking_ms);
  void Ack(const stitch::frame_t& frame);

  bus::Publisher* publisher_;
  TrackerOptions options_;
  std::string record_path_;
  bus::Subscriber subscriber_;
  BoundedQueue<std::unique_ptr<stitch::frame_t>> queue_;
  std::unique_ptr<Heartbeat> heartbeat_;
  std::unique_ptr<FrameTracker> tracker_;  // created from the first frame's camera
  std::mutex record_mutex_;  // Report() runs in the worker and the dispatcher thread
  std::ofstream record_;
  std::thread worker_;
  std::atomic<bool> running_{false};
  std::atomic<int64_t> received_{0}, tracked_{0}, dropped_{0};
  std::atomic<int> highest_received_{-1}, highest_processed_{-1};
};

}  // namespace stitch
