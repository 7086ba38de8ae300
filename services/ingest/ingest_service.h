#pragma once
// The ingest service: plays an ImageSequence onto the bus as frame_t messages on <agent>/FRAME,
// with the failure schedule applied, paced in real time or in lockstep with the tracker.
// Play() runs in the caller's thread; the bus dispatcher (another thread) delivers acks.

#include <atomic>
#include <condition_variable>
#include <mutex>
#include <string>

#include "services/common/bus.h"
#include "stitch/config/ingest_options.h"
#include "stitch/frame_ack_t.hpp"
#include "stitch/geo/gnss_fix.h"
#include "stitch/io/failure_schedule.h"
#include "stitch/io/image_sequence.h"
#include "stitch/service_status_t.hpp"

namespace stitch {

struct IngestSummary {
  int frames_published = 0;
  int frames_replaced = 0;    // spoiled by the failure schedule
  int frames_unreadable = 0;  // the source could not read them; sent empty so they are counted
  int frames_unacked = 0;     // lockstep: given up on after max_resends
  int resends = 0;
  int gnss_fixes_published = 0;
  int64_t frames_dropped_at_source = 0;  // live: captured, but a newer frame came before it could be sent
  int64_t acks_refused = 0;              // acks for frames not sent yet (forged)
  // Real-time playback of a recorded sequence: frames the source had ready more than one frame
  // period (at the playback speed) after their time, and how late the latest went out. Where
  // there are any, the run played slower than the camera (source_record.h).
  int frames_late = 0;
  double most_late_s = 0;
  double seconds = 0;
  bool stopped = false;  // ended by the stop flag, not by the end of the sequence
};

// Resolves the `auto` frame encoding for a bus: raw gray8 where whole frames fit the receive
// path (memq://, or udpm:// when the kernel allows a receive buffer of at least 1 MiB,
// net.core.rmem_max), JPEG otherwise, since UDP drops the fragments of large messages that
// overflow a small buffer. Other settings are returned unchanged.
std::string ChooseFrameEncoding(const std::string& setting, const std::string& lcm_url);

class IngestService {
 public:
  // Subscribes at once: construct before the Dispatcher starts. Frames go out through
  // `frame_publisher` (the frame bus, bus.frame_url; null: `publisher`, the bus `lcm` is);
  // `frame_url` is the URL they go out on (it decides the `auto` encoding).
  IngestService(lcm::LCM* lcm, const std::string& frame_url, bus::Publisher* publisher, IngestOptions options,
                bus::Publisher* frame_publisher = nullptr);

  // Plays `sequence` to its end or until `stop`. `spoil` names frames to replace by unusable
  // ones (datasets; the synthetic flight renders its gusts itself). Throws stitch::Error when
  // lockstep finds no tracker.
  // `gnss`: the source's GNSS fixes (in time order), each published on <agent>/GNSS just before
  // the first frame at or after its time; those more than a second before the first frame or
  // after the last are not sent.
  IngestSummary Play(ImageSequence& sequence, const FailureSchedule& spoil, const std::atomic<bool>& stop,
                     const std::vector<GnssFix>& gnss = {});

  // Waits (at most options.wait_for_tracker_s) for a tracker on the bus; true once one runs. A
  // live camera is best opened after it: its frames do not wait.
  bool WaitForTracker(const std::atomic<bool>& stop);

  int64_t frames_published() const { return published_.load(); }
  int64_t rejected() const { return subscriber_.rejected(); }

 private:
  bool WaitForAck(int frame_index, const std::atomic<bool>& stop);
  void PublishSequenceInfo(const ImageSequence& sequence, const IngestSummary& summary, bool finished);

  bus::Publisher* publisher_;
  bus::Publisher* frame_publisher_;
  IngestOptions options_;
  bus::Subscriber subscriber_;
  std::mutex mutex_;
  std::condition_variable changed_;
  int highest_acked_ = -1;
  int highest_sent_ = -1;  // acks for frames after it are refused
  int64_t acks_refused_ = 0;
  bool tracker_running_ = false;
  std::atomic<int64_t> published_{0};
};

}  // namespace stitch
