#include "services/ingest/ingest_service.h"

#include <algorithm>
#include <fstream>
#include <thread>

#include "services/common/convert.h"
#include "stitch/frame_t.hpp"
#include "stitch/sequence_info_t.hpp"
#include "stitch/util/log.h"
#include "stitch/util/options.h"
#include "stitch/util/time.h"

namespace stitch {

std::string ChooseFrameEncoding(const std::string& setting, const std::string& lcm_url) {
  if (setting != "auto") return setting;
  if (lcm_url.rfind("udpm://", 0) != 0) return "gray8";
  std::ifstream limit("/proc/sys/net/core/rmem_max");
  long bytes = 0;
  if (limit >> bytes && bytes >= (1 << 20)) return "gray8";
  STITCH_LOG(INFO) << "net.core.rmem_max is " << bytes
                   << " bytes: too small for raw frames over UDP, sending JPEG (raise it to 2097152 for raw frames)";
  return "jpeg";
}

IngestService::IngestService(lcm::LCM* lcm, const std::string& frame_url, bus::Publisher* publisher,
                             IngestOptions options, bus::Publisher* frame_publisher)
    : publisher_(publisher),
      frame_publisher_(frame_publisher ? frame_publisher : publisher),
      options_(std::move(options)),
      subscriber_(lcm, publisher->authenticator()) {
  CheckOptions(options_, "ingest");
  options_.encoding = ChooseFrameEncoding(options_.encoding, frame_url);
  const std::string agent = publisher_->agent();
  subscriber_.Subscribe<stitch::frame_ack_t>(bus::Channel(agent, bus::kFrameAck),
                                             [this](std::unique_ptr<stitch::frame_ack_t> ack, const std::string&) {
                                               if (ack->frame_session != publisher_->session())
                                                 return;  // another ingest's (or an earlier run's) frame
                                               std::lock_guard<std::mutex> lock(mutex_);
                                               if (ack->frame_index > highest_sent_) {
                                                 ++acks_refused_;  // for a frame not sent yet: forged
                                                 return;
                                               }
                                               highest_acked_ = std::max(highest_acked_, ack->frame_index);
                                               changed_.notify_all();
                                             });
  subscriber_.Subscribe<stitch::service_status_t>(
      bus::Channel(agent, bus::kService), [this](std::unique_ptr<stitch::service_status_t> status, const std::string&) {
        if (status->service != "tracker") return;
        std::lock_guard<std::mutex> lock(mutex_);
        tracker_running_ = status->state == stitch::service_status_t::STATE_RUNNING;
        changed_.notify_all();
      });
}

bool IngestService::WaitForTracker(const std::atomic<bool>& stop) {
  const double deadline = MonotonicSeconds() + options_.wait_for_tracker_s;
  std::unique_lock<std::mutex> lock(mutex_);
  while (!tracker_running_ && !stop.load() && MonotonicSeconds() < deadline) {
    changed_.wait_for(lock, std::chrono::milliseconds(100));
  }
  return tracker_running_;
}

bool IngestService::WaitForAck(int frame_index, const std::atomic<bool>& stop) {
  const double deadline = MonotonicSeconds() + options_.ack_timeout_s;
  std::unique_lock<std::mutex> lock(mutex_);
  while (highest_acked_ < frame_index && !stop.load() && MonotonicSeconds() < deadline) {
    changed_.wait_for(lock, std::chrono::milliseconds(20));
  }
  return highest_acked_ >= frame_index;
}

void IngestService::PublishSequenceInfo(const ImageSequence& sequence, const IngestSummary& summary, bool finished) {
  stitch::sequence_info_t info{};
  info.source = sequence.description();
  info.frames_total = sequence.size();
  info.frames_published = summary.frames_published;
  info.frames_replaced = summary.frames_replaced;
  info.frames_unacked = summary.frames_unacked;
  info.nominal_fps = sequence.nominal_fps();
  info.finished = finished;
  publisher_->Publish(bus::Channel(publisher_->agent(), bus::kSequence), &info);
}

IngestSummary IngestService::Play(ImageSequence& sequence, const FailureSchedule& spoil, const std::atomic<bool>& stop,
                                  const std::vector<GnssFix>& gnss) {
  // A live camera does not wait for anyone: its frames go out as they come.
  const bool live = sequence.live();
  const bool lockstep = options_.pacing == "lockstep" && !live;
  if (live && options_.pacing == "lockstep") {
    STITCH_LOG(INFO) << "a live source is played as it comes (lockstep pacing does not apply)";
  }
  const ImageEncoding encoding = ParseImageEncoding(options_.encoding);
  const FailureStyle failure_style = ParseFailureStyle(options_.failure_style);
  const std::string frame_channel = bus::Channel(publisher_->agent(), bus::kFrame);
  IngestSummary summary;
  const std::string gnss_channel = bus::Channel(publisher_->agent(), bus::kGnss);
  size_t next_fix = 0;
  // The fixes up to `t_ns` not sent yet, from a second before the first frame on.
  const auto publish_fixes_until = [&](int64_t t_ns, int64_t first_t_ns) {
    for (; next_fix < gnss.size() && gnss[next_fix].t_ns <= t_ns; ++next_fix) {
      if (gnss[next_fix].t_ns < first_t_ns - 1'000'000'000) continue;
      stitch::gnss_fix_t fix = ToMessage(gnss[next_fix]);
      publisher_->Publish(gnss_channel, &fix);
      ++summary.gnss_fixes_published;
    }
  };
  STITCH_LOG(INFO) << "playing " << sequence.description() << ", " << (live ? "live" : options_.pacing) << " pacing, "
                   << options_.encoding << " frames"
                   << (spoil.empty() ? std::string() : ", spoiling frames " + spoil.ToString());
  // A recording played at its camera's rate starts once a tracker runs, as a flight starts once
  // the aircraft's computer is up: the frames sent before it listened were lost to every run
  // (TUM at twice its rate: the first 7). A live camera's frames go out as they come; both go on
  // without a tracker once the wait is over.
  if (!lockstep && !WaitForTracker(stop) && !stop.load()) {
    STITCH_LOG(WARNING) << "no tracker answered within " << options_.wait_for_tracker_s
                        << " s on this bus; sending the " << (live ? "live" : "real-time") << " frames anyway";
  }
  if (lockstep && !WaitForTracker(stop)) {
    if (stop.load()) {
      summary.stopped = true;
      return summary;
    }
    throw Error("lockstep pacing: no tracker answered within " + std::to_string(options_.wait_for_tracker_s) +
                " s on this bus; start a tracker with the same --lcm-url and --agent, or use --pacing realtime");
  }

  const Stopwatch clock;
  double last_info = -1;
  int64_t first_t_ns = 0;
  double first_ready_s = 0;
  bool first = true;
  SequenceFrame frame;
  stitch::frame_t message{};
  message.camera = ToMessage(sequence.camera());
  message.camera_id = 0;
  message.pacing = lockstep ? stitch::frame_t::PACING_LOCKSTEP : stitch::frame_t::PACING_LIVE;
  // Real-time playback: a frame the source has ready later than this after its time is late.
  const double frame_period_s = 1.0 / ((sequence.nominal_fps() > 0 ? sequence.nominal_fps() : 30.0) * options_.speed);
  while (!stop.load() && sequence.Next(&frame)) {
    if (first) {
      first_t_ns = frame.t_ns;
      first_ready_s = clock.ElapsedSeconds();  // the camera starts when its first frame is there
      first = false;
    }
    if (!lockstep && !live) {
      // The camera does not wait: each frame goes out at its time, whatever the consumers do.
      const double due = first_ready_s + (frame.t_ns - first_t_ns) * 1e-9 / options_.speed;
      const double wait = due - clock.ElapsedSeconds();
      if (wait > 0) {
        std::this_thread::sleep_for(std::chrono::duration<double>(wait));
      } else if (-wait > frame_period_s) {
        ++summary.frames_late;  // the source cannot keep the pace: the run plays slower than the camera
        summary.most_late_s = std::max(summary.most_late_s, -wait);
      }
    }
    message.t_ns = frame.t_ns;
    message.frame_index = frame.index;
    message.frames_total = sequence.size();
    if (frame.image.empty()) {
      // Sent empty so the tracker can count it and say why.
      STITCH_LOG(WARNING) << "frame " << frame.index << " unreadable: " << frame.error;
      ++summary.frames_unreadable;
      message.encoding = stitch::frame_t::ENCODING_GRAY8;
      message.width = sequence.camera().width();
      message.height = sequence.camera().height();
      message.data.clear();
      message.num_bytes = 0;
    } else {
      if (spoil.Contains(frame.index)) {
        SpoilImage(&frame.image, failure_style, frame.index, static_cast<uint64_t>(options_.failure_seed));
        ++summary.frames_replaced;
      }
      EncodeImage(frame.image, encoding, options_.jpeg_quality, &message);
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      highest_sent_ = std::max(highest_sent_, frame.index);
    }
    publish_fixes_until(frame.t_ns, first_t_ns);
    frame_publisher_->Publish(frame_channel, &message);
    ++summary.frames_published;
    ++published_;
    if (lockstep) {
      int resends = 0;
      while (!WaitForAck(frame.index, stop) && !stop.load()) {
        if (resends == options_.max_resends) {
          STITCH_LOG(WARNING) << "frame " << frame.index << ": no ack after " << resends
                              << " re-sends; going on without it";
          ++summary.frames_unacked;
          break;
        }
        ++resends;
        ++summary.resends;
        frame_publisher_->Publish(frame_channel, &message);
      }
    }
    if (clock.ElapsedSeconds() - last_info >= 1.0) {
      last_info = clock.ElapsedSeconds();
      PublishSequenceInfo(sequence, summary, false);
    }
  }
  summary.stopped = stop.load();
  summary.seconds = clock.ElapsedSeconds();
  summary.frames_dropped_at_source = sequence.dropped_at_source();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    summary.acks_refused = acks_refused_;
  }
  if (summary.acks_refused > 0) {
    STITCH_LOG(WARNING) << "refused " << summary.acks_refused
                        << " acks for frames not sent yet (forged, or from another ingest with this session)";
  }
  // The end of the sequence is state that matters: say it a few times (UDP may lose one).
  for (int i = 0; i < 3; ++i) {
    PublishSequenceInfo(sequence, summary, true);
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  STITCH_LOG(INFO) << "published " << summary.frames_published << " frames in " << summary.seconds << " s ("
                   << summary.frames_replaced << " spoiled, " << summary.frames_unreadable << " unreadable, "
                   << summary.frames_unacked << " unacknowledged, " << summary.resends << " re-sends"
                   << (gnss.empty() ? std::string()
                                    : ", " + std::to_string(summary.gnss_fixes_published) + " GNSS fixes")
                   << (live ? ", " + std::to_string(summary.frames_dropped_at_source) +
                                  " captured but replaced by a newer one before they could be sent"
                            : std::string())
                   << ")";
  if (summary.frames_late > 0) {
    STITCH_LOG(WARNING) << summary.frames_late << " frames went out more than a frame late (up to "
                        << summary.most_late_s << " s): the source could not keep the camera's pace, so "
                        << "the run played slower than the camera";
  }
  return summary;
}

}  // namespace stitch
