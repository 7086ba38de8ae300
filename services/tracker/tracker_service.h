#pragma once
// The tracker service: receives frames on <agent>/FRAME and the mapper's updates on
// <agent>/LOCAL_MAP; tracks each frame with Tracking in its own worker thread; publishes a
// tracking_status_t per frame, a frame_ack_t (lockstep pacing) and new keyframes on
// <agent>/KEYFRAME (made and sent on a thread of their own with tracker.tracking.keyframe_worker,
// the frame's ack behind them). Frames that arrive twice are acknowledged again but tracked
// once; frames that arrive after a newer one, or that wait while the queue is full (real-time),
// are reported as dropped. Writes one line per frame to `record_path` (frames.tsv) when given,
// on disk before the frame's ack, appending to what an earlier run of the tracker wrote there.
// With a state file, submap numbers continue where the last run of the tracker left them.

#include <atomic>
#include <fstream>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "services/common/bus.h"
#include "services/common/service.h"
#include "stitch/config/tracker_options.h"
#include "stitch/frame_ack_t.hpp"
#include "stitch/frame_t.hpp"
#include "stitch/keyframe_t.hpp"
#include "stitch/local_map_update_t.hpp"
#include "stitch/mosaic/keyframe_imagery.h"
#include "stitch/service_status_t.hpp"
#include "stitch/tracking/tracking.h"
#include "stitch/util/bounded_queue.h"
#include "stitch/util/worker_thread.h"

namespace stitch {

// A tracking state as tracking_status_t carries it (STATE_*).
int8_t ToMessageState(TrackingState state);

class TrackerService {
 public:
  // Subscribes at once: construct before the Dispatcher starts. `vocabulary` must outlive it.
  // Frames come on `frame_lcm` (the frame bus, bus.frame_url; null: `lcm`).
  TrackerService(lcm::LCM* lcm, bus::Publisher* publisher, TrackerOptions options, const Vocabulary* vocabulary,
                 std::string record_path, lcm::LCM* frame_lcm = nullptr);
  ~TrackerService();

  void Start();
  // Tracks what is queued, writes the record, stops the worker.
  void Stop();

  int64_t frames_received() const { return received_.load(); }
  int64_t frames_tracked() const { return tracked_.load(); }
  int64_t keyframes_published() const { return keyframes_.load(); }
  // Times the worker held a frame back to wait for the mapper (lockstep frames only).
  int64_t mapper_waits() const { return mapper_waits_.load(); }
  // Times the worker waited for a keyframe's new points on a thin map (live frames), and how
  // long in all.
  int64_t points_waits() const { return points_waits_.load(); }
  double points_wait_s() const { return points_wait_s_.load(); }

 private:
  void OnFrame(std::unique_ptr<stitch::frame_t> frame);
  void Work();
  void ApplyUpdates(std::chrono::milliseconds wait);
  void WaitForMapper();
  // Live frames: after a keyframe, on a thin map, a short wait for its new points
  // (TrackerOptions::live_wait_for_points_s).
  void WaitForNewPoints();
  // Live frames: a mapper silent for mapper_timeout_s with keyframes unanswered is reported absent.
  void WatchMapper();
  void Process(const stitch::frame_t& frame);
  // The frame's status, then RecordFrame.
  void Report(const stitch::frame_t& frame, const TrackResult& result, float tracking_ms);
  // The pose stream (a tracked frame) and the frame's line in frames.tsv.
  void RecordFrame(int frame_index, int64_t t_ns, const TrackResult& result, float tracking_ms);
  void Ack(const stitch::frame_t& frame);
  void PublishAck(stitch::frame_ack_t ack);
  void SaveState();
  // Reports and acknowledges the dropped frames older than `before` (all of them when null).
  // Worker thread only.
  void ReportDroppedFrames(const stitch::frame_t* before);
  // A dropped frame not reported yet: a re-send of it is neither late nor new.
  bool AwaitsReport(const stitch::frame_t& frame);
  // Copies what Report() says of tracking_ into the atomics it reads. Worker thread only.
  void RefreshReportedState();
  // Makes the keyframe's message, sends it, keeps it until the mapper covers it.
  void PublishKeyframe(const Keyframe& keyframe, const std::vector<MapPoint>& new_points);
  // A keyframe's reduced picture for the ground (tracker.keyframe_images), made from `image`.
  void PublishKeyframeImage(KeyframeId id, int frame_index, int64_t t_ns, const cv::Mat& image);

  bus::Publisher* publisher_;
  TrackerOptions options_;
  const Vocabulary* vocabulary_;
  std::string record_path_;
  bus::Subscriber subscriber_;
  bus::Subscriber frame_subscriber_;
  BoundedQueue<std::unique_ptr<stitch::frame_t>> frames_;
  BoundedQueue<std::unique_ptr<stitch::local_map_update_t>> updates_;
  std::unique_ptr<Heartbeat> heartbeat_;
  std::unique_ptr<Tracking> tracking_;  // created from the first frame's camera
  // New keyframes' messages are made and sent here with tracker.tracking.keyframe_worker (off
  // the frame loop), and frames' acks behind them; Drain() before reading unacknowledged_keyframes_
  // in the worker thread.
  std::unique_ptr<WorkerThread> publisher_thread_;
  KeyframeImagePicker image_picker_;  // worker thread only
  std::mutex unacknowledged_mutex_;
  std::vector<stitch::keyframe_t> unacknowledged_keyframes_;  // sent, not yet covered by an update
  std::mutex record_mutex_;                                   // Report() runs in the worker and the dispatcher thread
  // Frames the queue dropped for newer ones (their images cleared), for the worker to report
  // in frame order: ReportDroppedFrames().
  std::mutex dropped_frames_mutex_;
  std::vector<std::unique_ptr<stitch::frame_t>> dropped_frames_;
  std::ofstream record_;
  bool record_failed_ = false;  // said once
  std::thread worker_;
  // The last frame came from a live source (frame_t::pacing): the tracker never waits for the
  // mapper's answer then (only, on a thin map, a moment for a keyframe's points:
  // WaitForNewPoints); it makes keyframes as the mapper takes them. Worker thread only.
  bool live_ = false;
  double mapper_heard_at_ = 0;      // the last update applied, or the first keyframe it left unanswered
  int last_tracked_points_ = 0;     // map points the last frame tracked (WaitForNewPoints)
  KeyframeId waited_for_keyframe_;  // the keyframe WaitForNewPoints last waited for
  // When this agent's mapper last said it was running (its heartbeat, about 1 Hz; 0: never).
  std::atomic<double> mapper_alive_at_{0};
  std::atomic<bool> running_{false};
  std::atomic<int64_t> received_{0}, tracked_{0}, dropped_{0}, keyframes_{0}, mapper_waits_{0}, points_waits_{0};
  std::atomic<double> points_wait_s_{0};
  std::atomic<int> highest_received_{-1}, highest_processed_{-1};  // frame numbers of...
  std::atomic<int64_t> ingest_session_{0};                         // ...this ingest's frames
  // tracking_'s state for Report(), which also runs in the dispatcher thread (late and dropped
  // frames) and so must not touch tracking_; the worker refreshes them (RefreshReportedState).
  std::atomic<bool> mapper_connected_{false};
  std::atomic<int> submaps_closed_{0};
  std::atomic<int> first_submap_held_{1};
  int saved_submap_number_ = -1;
};

}  // namespace stitch
