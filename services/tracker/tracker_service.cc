#include "services/tracker/tracker_service.h"

#include <algorithm>
#include <cmath>
#include <filesystem>

#include "services/common/convert.h"
#include "services/common/map_convert.h"
#include "stitch/frame_ack_t.hpp"
#include "stitch/keyframe_image_t.hpp"
#include "stitch/records/frame_record.h"
#include "stitch/records/tracker_state.h"
#include "stitch/tracking_status_t.hpp"
#include "stitch/util/log.h"
#include "stitch/util/options.h"
#include "stitch/util/time.h"

namespace stitch {

namespace {
// Frames a session may skip at once (lost on the network, dropped at a live source): a minute at 30 fps.
constexpr int kMaxFrameIndexJump = 1800;

}  // namespace

int8_t ToMessageState(TrackingState state) {
  switch (state) {
    case TrackingState::kInitializing:
      return stitch::tracking_status_t::STATE_INITIALIZING;
    case TrackingState::kOk:
      return stitch::tracking_status_t::STATE_OK;
    case TrackingState::kLost:
      return stitch::tracking_status_t::STATE_LOST;
    case TrackingState::kSkipped:
      return stitch::tracking_status_t::STATE_SKIPPED;
    case TrackingState::kNotTracked:
      return stitch::tracking_status_t::STATE_NOT_TRACKED;
  }
  return stitch::tracking_status_t::STATE_NOT_TRACKED;
}

namespace {

stitch::frame_ack_t AckOf(const stitch::frame_t& frame) {
  stitch::frame_ack_t ack{};
  ack.frame_index = frame.frame_index;
  ack.t_ns = frame.t_ns;
  ack.frame_session = frame.header.sender_session;
  return ack;
}

}  // namespace

TrackerService::TrackerService(lcm::LCM* lcm, bus::Publisher* publisher, TrackerOptions options,
                               const Vocabulary* vocabulary, std::string record_path, lcm::LCM* frame_lcm)
    : publisher_(publisher),
      options_(std::move(options)),
      vocabulary_(vocabulary),
      record_path_(std::move(record_path)),
      subscriber_(lcm, publisher->authenticator()),
      frame_subscriber_(frame_lcm ? frame_lcm : lcm, publisher->authenticator()),
      frames_(static_cast<size_t>(std::max(1, options_.max_queued_frames)),
              BoundedQueue<std::unique_ptr<stitch::frame_t>>::WhenFull::kDropOldest),
      updates_(512, BoundedQueue<std::unique_ptr<stitch::local_map_update_t>>::WhenFull::kDropOldest),
      image_picker_(options_.keyframe_images) {
  CheckOptions(options_, "tracker");
  if (!vocabulary_ || vocabulary_->empty()) throw Error("the tracker needs a vocabulary");
  // Before the first frame can arrive: the dispatcher thread queues acks on it too (OnFrame).
  if (options_.tracking.keyframe_worker) publisher_thread_ = std::make_unique<WorkerThread>();
  const std::string agent = publisher_->agent();
  frame_subscriber_.Subscribe<stitch::frame_t>(
      bus::Channel(agent, bus::kFrame),
      [this](std::unique_ptr<stitch::frame_t> frame, const std::string&) { OnFrame(std::move(frame)); });
  subscriber_.Subscribe<stitch::local_map_update_t>(bus::Channel(agent, bus::kLocalMap),
                                                    [this](std::unique_ptr<stitch::local_map_update_t> update,
                                                           const std::string&) { updates_.Push(std::move(update)); });
  subscriber_.Subscribe<stitch::service_status_t>(
      bus::Channel(agent, bus::kService), [this](std::unique_ptr<stitch::service_status_t> status, const std::string&) {
        if (status->service == "mapper" && status->state == stitch::service_status_t::STATE_RUNNING)
          mapper_alive_at_ = MonotonicSeconds();
      });
  heartbeat_ = std::make_unique<Heartbeat>(publisher_, "tracker", [this] {
    return Heartbeat::Counts{received_.load(), tracked_.load(),
                             subscriber_.rejected() + frame_subscriber_.rejected() + dropped_.load()};
  });
  if (!record_path_.empty()) record_ = AppendToFrameRecord(record_path_);
  if (!options_.state_file.empty()) {
    const int next = ReadNextSubmapNumber(options_.state_file);
    if (next > options_.tracking.first_submap_number) {
      STITCH_LOG(INFO) << "resuming: submaps continue from number " << next << " (" << options_.state_file << ")";
      options_.tracking.first_submap_number = next;
    }
  }
  first_submap_held_ = options_.tracking.first_submap_number;
}

void TrackerService::RefreshReportedState() {
  if (!tracking_) return;
  mapper_connected_ = tracking_->mapper_connected();
  submaps_closed_ = tracking_->submaps_closed();
  first_submap_held_ = tracking_->first_submap_held();
}

void TrackerService::SaveState() {
  if (options_.state_file.empty() || !tracking_ || tracking_->next_submap_number() == saved_submap_number_) return;
  try {
    WriteNextSubmapNumber(options_.state_file, tracking_->next_submap_number());
    saved_submap_number_ = tracking_->next_submap_number();
  } catch (const std::exception& e) {
    STITCH_LOG(ERROR) << "cannot keep the submap number: " << e.what();
  }
}

TrackerService::~TrackerService() {
  Stop();
}

void TrackerService::Start() {
  if (running_.exchange(true)) return;
  worker_ = std::thread([this] { Work(); });
  heartbeat_->Start();
  heartbeat_->SetState(stitch::service_status_t::STATE_RUNNING);
}

void TrackerService::Stop() {
  if (!running_.exchange(false)) return;
  frames_.Close();
  if (worker_.joinable()) worker_.join();
  if (publisher_thread_) publisher_thread_->Drain();  // sends what is queued
  updates_.Close();
  heartbeat_->SetState(stitch::service_status_t::STATE_FINISHED);
  heartbeat_->Stop();
}

void TrackerService::OnFrame(std::unique_ptr<stitch::frame_t> frame) {
  // Runs in the dispatcher thread: decide, enqueue, return.
  // A new ingest (restarted, or the next flight) numbers its frames afresh: what an earlier one
  // sent says nothing about which of its frames are duplicates or late.
  if (frame->header.sender_session != ingest_session_.load()) {
    if (ingest_session_.load() != 0) {
      STITCH_LOG(INFO) << "frames from a new ingest session: their numbering starts over";
    }
    ingest_session_ = frame->header.sender_session;
    highest_received_ = -1;
    highest_processed_ = -1;
  }
  // Within a session frames are numbered in order; a frame far ahead of the newest one (a forged
  // 2^31-1 made every later real frame look "already tracked") is refused, not acknowledged.
  if (frame->frame_index < 0 ||
      (highest_received_.load() >= 0 && frame->frame_index > highest_received_.load() + kMaxFrameIndexJump)) {
    frame_subscriber_.Reject(
        bus::Channel(publisher_->agent(), bus::kFrame),
        "jumps to frame " + std::to_string(frame->frame_index) + " from " + std::to_string(highest_received_.load()));
    return;
  }
  if (frame->frame_index <= highest_processed_.load()) {
    // A re-send of a frame already tracked (its ack was lost or is late): acknowledged again, but
    // behind the keyframes it made, which may still be on their way out.
    if (publisher_thread_) {
      publisher_thread_->Submit([this, ack = AckOf(*frame)] { PublishAck(ack); });
    } else {
      Ack(*frame);
    }
    return;
  }
  if (frame->frame_index <= highest_received_.load()) {
    if (frame->frame_index < highest_received_.load() && !AwaitsReport(*frame)) {
      TrackResult late;
      late.state = TrackingState::kSkipped;
      late.reason = TrackingReason::kDropped;
      late.detail = "arrived after a newer frame";
      Report(*frame, late, 0.0f);
      Ack(*frame);
    }
    return;  // an exact duplicate of a queued frame is acknowledged when it is tracked
  }
  highest_received_ = frame->frame_index;
  ++received_;
  if (auto dropped = frames_.Push(std::move(frame))) {
    // Reported and acknowledged by the worker, between the frames it tracks: frames.tsv and
    // TRACKING_STATUS stay in frame order (this thread would write the line while the worker
    // tracks an older frame).
    ++dropped_;
    (*dropped)->data.clear();
    (*dropped)->num_bytes = 0;
    std::lock_guard<std::mutex> lock(dropped_frames_mutex_);
    dropped_frames_.push_back(std::move(*dropped));
  }
}

bool TrackerService::AwaitsReport(const stitch::frame_t& frame) {
  std::lock_guard<std::mutex> lock(dropped_frames_mutex_);
  return std::any_of(dropped_frames_.begin(), dropped_frames_.end(), [&](const auto& dropped) {
    return dropped->frame_index == frame.frame_index && dropped->header.sender_session == frame.header.sender_session;
  });
}

void TrackerService::ReportDroppedFrames(const stitch::frame_t* before) {
  std::vector<std::unique_ptr<stitch::frame_t>> due;
  {
    std::lock_guard<std::mutex> lock(dropped_frames_mutex_);
    auto kept = dropped_frames_.begin();
    for (auto& frame : dropped_frames_) {
      const bool older = !before || frame->header.sender_session != before->header.sender_session ||
                         frame->frame_index < before->frame_index;
      if (older) {
        due.push_back(std::move(frame));
      } else {
        *kept++ = std::move(frame);
      }
    }
    dropped_frames_.erase(kept, dropped_frames_.end());
  }
  for (const auto& frame : due) {
    TrackResult result;
    result.state = TrackingState::kSkipped;
    result.reason = TrackingReason::kDropped;
    result.detail = "tracker busy (real-time pacing)";
    Report(*frame, result, 0.0f);
    Ack(*frame);
  }
}

void TrackerService::ApplyUpdates(std::chrono::milliseconds wait) {
  auto update = updates_.Pop(wait);
  while (update) {
    if (tracking_) {
      try {
        // Only the last part of an update says the keyframe is done.
        tracking_->ApplyUpdate(FromMessage(**update), (*update)->part == (*update)->num_parts - 1);
        mapper_heard_at_ = MonotonicSeconds();
      } catch (const Error& e) {
        STITCH_LOG(WARNING) << "ignored a local map update: " << e.what();
      }
    }
    update = updates_.Pop(std::chrono::milliseconds(0));
  }
}

void TrackerService::WaitForMapper() {
  if (!tracking_ || !options_.wait_for_mapper || live_ || tracking_->MapperCaughtUp() || !tracking_->mapper_connected())
    return;
  // Lockstep with the mapper: the next frame sees the map the mapper made from the last keyframe.
  // However long that takes while the mapper says it is running (a slow or starved machine, a
  // sanitizer build): giving up then would make the run depend on the machine's load.
  ++mapper_waits_;
  const double started = MonotonicSeconds();
  const double longest = std::max(options_.mapper_busy_max_wait_s, options_.mapper_timeout_s);
  bool sent_again = false;
  while (!tracking_->MapperCaughtUp() && running_.load()) {
    ApplyUpdates(std::chrono::milliseconds(20));
    const double now = MonotonicSeconds();
    if (!sent_again && now - started > options_.mapper_timeout_s / 2 && !tracking_->MapperCaughtUp()) {
      // The keyframe (or the mapper's answer) may have been lost: send it again, once.
      sent_again = true;
      if (publisher_thread_) publisher_thread_->Drain();
      std::lock_guard<std::mutex> lock(unacknowledged_mutex_);
      for (auto& keyframe : unacknowledged_keyframes_)
        publisher_->Publish(bus::Channel(publisher_->agent(), bus::kKeyframe), &keyframe);
    }
    const double heard = std::max(started, mapper_alive_at_.load());
    if (now - heard > options_.mapper_timeout_s || now - started > longest) break;
  }
  if (!running_.load()) return;  // stopping: no more frames to hold back
  if (!tracking_->MapperCaughtUp()) {
    STITCH_LOG(WARNING) << "no answer from the mapper for keyframe " << tracking_->last_keyframe_sent() << " within "
                        << MonotonicSeconds() - started << " s; tracking on without it";
    tracking_->SetMapperConnected(false);
  }
}

void TrackerService::WaitForNewPoints() {
  if (!tracking_ || !live_ || options_.live_wait_for_points_s <= 0 || !tracking_->mapper_connected() ||
      last_tracked_points_ >= options_.live_wait_below_points || tracking_->NewestKeyframePointsReceived() ||
      waited_for_keyframe_ == tracking_->last_keyframe_sent())
    return;
  // A thin map: the next frame may lose track where the newest keyframe's points would hold it.
  waited_for_keyframe_ = tracking_->last_keyframe_sent();
  ++points_waits_;
  const double started = MonotonicSeconds();
  const double deadline = started + options_.live_wait_for_points_s;
  while (!tracking_->NewestKeyframePointsReceived() && running_.load()) {
    const double left = deadline - MonotonicSeconds();
    if (left <= 0) break;
    ApplyUpdates(std::chrono::milliseconds(std::max(1, static_cast<int>(std::ceil(left * 1000)))));
  }
  points_wait_s_.store(points_wait_s_.load() + MonotonicSeconds() - started);  // one writer: the worker
}

void TrackerService::WatchMapper() {
  if (!tracking_ || !live_) return;
  const double now = MonotonicSeconds();
  if (tracking_->MapperCaughtUp() || mapper_heard_at_ == 0) {
    mapper_heard_at_ = now;  // nothing asked of it (yet): silence says nothing
    return;
  }
  if (tracking_->mapper_connected() && now - mapper_heard_at_ > options_.mapper_timeout_s) {
    STITCH_LOG(WARNING) << "no answer from the mapper for " << tracking_->KeyframesInFlight() << " keyframe(s) within "
                        << options_.mapper_timeout_s << " s; making keyframes without it";
    tracking_->SetMapperConnected(false);
  }
}

void TrackerService::Work() {
  while (true) {
    ApplyUpdates(std::chrono::milliseconds(0));
    WaitForMapper();
    WaitForNewPoints();
    WatchMapper();
    RefreshReportedState();
    if (tracking_ && tracking_->MapperCaughtUp()) {
      std::lock_guard<std::mutex> lock(unacknowledged_mutex_);
      unacknowledged_keyframes_.clear();
    }
    auto frame = frames_.Pop(std::chrono::milliseconds(20));
    if (!frame) {
      ReportDroppedFrames(nullptr);
      if (frames_.closed()) return;
      continue;
    }
    ReportDroppedFrames(frame->get());
    Process(**frame);
  }
}

void TrackerService::Process(const stitch::frame_t& frame) {
  const Stopwatch watch;
  live_ = frame.pacing != stitch::frame_t::PACING_LOCKSTEP;
  Tracking::Output output;
  cv::Mat image;
  try {
    if (tracking_ && (frame.width != tracking_->camera().width() || frame.height != tracking_->camera().height())) {
      throw Error("a " + std::to_string(frame.width) + "x" + std::to_string(frame.height) + " frame for a " +
                  std::to_string(tracking_->camera().width()) + "x" + std::to_string(tracking_->camera().height()) +
                  " camera; not decoded");
    }
    image = DecodeImage(frame);
    if (!tracking_) {
      const Camera camera = FromMessage(frame.camera);
      const double fps = 0;  // the tracker does not know the source's rate: one second of frames = 30
      tracking_ =
          std::make_unique<Tracking>(options_.tracking, camera, vocabulary_, fps, ParseLossPolicy(options_.on_loss));
      STITCH_LOG(INFO) << "camera " << camera.Describe() << " (tracking set up in " << std::lround(watch.ElapsedMs())
                       << " ms)";
    }
    output = tracking_->Track(image, frame.frame_index, frame.t_ns);
    last_tracked_points_ = output.result.num_tracked_points;
  } catch (const Error& e) {
    output.result.state = TrackingState::kSkipped;
    output.result.reason = TrackingReason::kUndecodableFrame;
    output.result.detail = e.what();
    STITCH_LOG(WARNING) << "frame " << frame.frame_index << " skipped: " << e.what();
  }
  const float ms = static_cast<float>(watch.ElapsedMs());
  for (size_t k = 0; k < output.new_keyframes.size(); ++k) {
    // The ground's picture of it, where its view moved on (only this frame's image is at hand).
    const Keyframe& made = output.new_keyframes[k];
    if (made.frame_index == frame.frame_index && tracking_ &&
        image_picker_.Take(SubmapOf(made.id).value, made.cam_from_world.Inverse(), tracking_->camera())) {
      if (publisher_thread_) {
        publisher_thread_->Submit([this, id = made.id, frame_index = made.frame_index, t_ns = made.t_ns, image] {
          PublishKeyframeImage(id, frame_index, t_ns, image);
        });
      } else {
        PublishKeyframeImage(made.id, made.frame_index, made.t_ns, image);
      }
    }
    std::vector<MapPoint> points = k == 0 ? std::move(output.new_points) : std::vector<MapPoint>();
    if (publisher_thread_) {
      publisher_thread_->Submit([this, keyframe = std::move(output.new_keyframes[k]), points = std::move(points)] {
        PublishKeyframe(keyframe, points);
      });
    } else {
      PublishKeyframe(output.new_keyframes[k], points);
    }
  }
  if (output.closed_submap) {
    STITCH_LOG(INFO) << "submap " << SubmapName(*output.closed_submap) << " closed";
  }
  if (output.reopened_submap) {
    STITCH_LOG(INFO) << "submap " << SubmapName(*output.reopened_submap) << " reopened";
  }
  SaveState();
  if (frame.header.sender_session == ingest_session_.load()) highest_processed_ = frame.frame_index;
  ++tracked_;
  RefreshReportedState();
  // Frames placed only now (those a new map initialized from, or missed ones placed backward): a
  // second, later line each (frame_record.h).
  for (const Tracking::EarlierFrame& earlier : output.earlier_frames) {
    RecordFrame(earlier.frame_index, earlier.t_ns, earlier.result, 0.0f);
  }
  Report(frame, output.result, ms);
  if (publisher_thread_) {
    // Behind the frame's keyframes: a frame is acknowledged once all it made is out, so a
    // tracker killed in between gets the frame again instead of losing its keyframe.
    publisher_thread_->Submit([this, ack = AckOf(frame)] { PublishAck(ack); });
  } else {
    Ack(frame);
  }
}

void TrackerService::PublishKeyframe(const Keyframe& keyframe, const std::vector<MapPoint>& new_points) {
  stitch::keyframe_t message = ToMessage(keyframe, tracking_->camera(), new_points);
  publisher_->Publish(bus::Channel(publisher_->agent(), bus::kKeyframe), &message);
  std::lock_guard<std::mutex> lock(unacknowledged_mutex_);
  unacknowledged_keyframes_.push_back(std::move(message));
  ++keyframes_;
}

void TrackerService::PublishKeyframeImage(KeyframeId id, int frame_index, int64_t t_ns, const cv::Mat& image) {
  stitch::keyframe_image_t message{};
  message.keyframe_id = id.value;
  message.submap_id = SubmapOf(id).value;
  message.frame_index = frame_index;
  message.t_ns = t_ns;
  message.camera_width = image.cols;
  message.camera_height = image.rows;
  try {
    cv::Size size;
    message.jpeg = EncodeKeyframePicture(image, options_.keyframe_images, &size);
    message.width = size.width;
    message.height = size.height;
  } catch (const Error& e) {
    STITCH_LOG(WARNING) << "keyframe of frame " << frame_index << ": no picture for the ground: " << e.what();
    return;
  }
  message.num_bytes = static_cast<int32_t>(message.jpeg.size());
  publisher_->Publish(bus::Channel(publisher_->agent(), bus::kKeyframeImage), &message);
}

void TrackerService::Report(const stitch::frame_t& frame, const TrackResult& result, float tracking_ms) {
  stitch::tracking_status_t status{};
  status.frame_index = frame.frame_index;
  status.t_ns = frame.t_ns;
  status.state = ToMessageState(result.state);
  status.reason = static_cast<int8_t>(result.reason);
  status.detail = result.detail;
  status.submap_id = result.submap.value;
  status.cam_from_submap = ToMessage(result.cam_from_submap.value_or(Rigid3d()));
  status.num_features = result.num_features;
  status.num_tracked_points = result.num_tracked_points;
  status.submap_keyframes = result.submap_keyframes;
  status.tracking_ms = tracking_ms;
  status.mapper_connected = mapper_connected_.load();
  status.submaps_closed = submaps_closed_.load();
  status.first_submap_held = first_submap_held_.load();
  publisher_->Publish(bus::Channel(publisher_->agent(), bus::kTrackingStatus), &status);
  RecordFrame(frame.frame_index, frame.t_ns, result, tracking_ms);
}

void TrackerService::RecordFrame(int frame_index, int64_t t_ns, const TrackResult& result, float tracking_ms) {
  if (result.state == TrackingState::kOk && result.cam_from_submap) {
    // The thin pose stream the ground places in the merged map (trajectory.tum on the ground).
    stitch::frame_pose_t pose = FramePoseMessage(frame_index, t_ns, result.submap, *result.cam_from_submap,
                                                 result.reference_keyframe, result.cam_from_reference);
    publisher_->Publish(bus::Channel(publisher_->agent(), bus::kPose), &pose);
  }
  if (record_.is_open()) {
    FrameRecord record;
    record.frame_index = frame_index;
    record.t_ns = t_ns;
    record.state = TrackingStateName(result.state);
    record.reason = static_cast<int>(result.reason);
    record.submap_id = result.submap.value;
    if (result.cam_from_submap) record.world_from_cam = result.cam_from_submap->Inverse();
    record.num_features = result.num_features;
    record.tracked_points = result.num_tracked_points;
    record.is_keyframe = result.is_keyframe;
    record.tracking_ms = tracking_ms;
    record.note = result.detail;
    if (result.reference_keyframe.valid() && result.cam_from_reference) {
      record.reference_keyframe = result.reference_keyframe.value;
      record.cam_from_reference = *result.cam_from_reference;
    }
    // On disk before the frame is acknowledged: ingest never sends an acknowledged frame again,
    // so a line still in a buffer when the tracker is killed would be a frame lost.
    std::lock_guard<std::mutex> lock(record_mutex_);
    if (!(record_ << FormatFrameRecord(record) << std::flush) && !record_failed_) {
      record_failed_ = true;
      STITCH_LOG(ERROR) << record_path_ << ": cannot write the frame record (disk full?); tracking goes on";
    }
  }
}

void TrackerService::Ack(const stitch::frame_t& frame) {
  PublishAck(AckOf(frame));
}

void TrackerService::PublishAck(stitch::frame_ack_t ack) {
  publisher_->Publish(bus::Channel(publisher_->agent(), bus::kFrameAck), &ack);
}

}  // namespace stitch
