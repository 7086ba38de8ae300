#include "services/tracker/tracker_service.h"

#include "services/common/convert.h"
#include "stitch/eval/frame_record.h"
#include "stitch/frame_ack_t.hpp"
#include "stitch/tracking_status_t.hpp"
#include "stitch/util/log.h"
#include "stitch/util/options.h"
#include "stitch/util/time.h"

namespace stitch {
namespace {

int8_t ToMessageState(TrackingState state) {
  switch (state) {
    case TrackingState::kInitializing: return stitch::tracking_status_t::STATE_INITIALIZING;
    case TrackingState::kOk: return stitch::tracking_status_t::STATE_OK;
    case TrackingState::kLost: return stitch::tracking_status_t::STATE_LOST;
    case TrackingState::kSkipped: return stitch::tracking_status_t::STATE_SKIPPED;
    case TrackingState::kNotTracked: return stitch::tracking_status_t::STATE_NOT_TRACKED;
  }
  return stitch::tracking_status_t::STATE_NOT_TRACKED;
}

int8_t ToMessageReason(TrackingReason reason) { return static_cast<int8_t>(reason); }

}  // namespace

TrackerService::TrackerService(lcm::LCM* lcm, bus::Publisher* publisher, TrackerOptions options,
                               std::string record_path)
    : publisher_(publisher),
      options_(std::move(options)),
      record_path_(std::move(record_path)),
      subscriber_(lcm),
      queue_(static_cast<size_t>(std::max(1, options_.max_queued_frames)),
             BoundedQueue<std::unique_ptr<stitch::frame_t>>::WhenFull::kDropOldest) {
  CheckOptions(options_, "tracker");
  subscriber_.Subscribe<stitch::frame_t>(
      bus::Channel(publisher_->agent(), bus::kFrame),
      [this](std::unique_ptr<stitch::frame_t> frame, const std::string&) { OnFrame(std::move(frame)); });
  heartbeat_ = std::make_unique<Heartbeat>(publisher_, "tracker", [this] {
    return Heartbeat::Counts{received_.load(), tracked_.load(), subscriber_.rejected() + dropped_.load()};
  });
  if (!record_path_.empty()) {
    record_.open(record_path_);
    if (!record_) throw Error(record_path_ + ": cannot write the tracker's frame record");
    record_ << FrameRecordHeader();
  }
}

TrackerService::~TrackerService() { Stop(); }

void TrackerService::Start() {
  if (running_.exchange(true)) return;
  worker_ = std::thread([this] { Work(); });
  heartbeat_->Start();
  heartbeat_->SetState(stitch::service_status_t::STATE_RUNNING);
}

void TrackerService::Stop() {
  if (!running_.exchange(false)) return;
  queue_.Close();
  if (worker_.joinable()) worker_.join();
  heartbeat_->SetState(stitch::service_status_t::STATE_FINISHED);
  heartbeat_->Stop();
  std::lock_guard<std::mutex> lock(record_mutex_);
  if (record_.is_open()) record_.flush();
}

void TrackerService::OnFrame(std::unique_ptr<stitch::frame_t> frame) {
  // Runs in the dispatcher thread: decide, enqueue, return.
  if (frame->frame_index <= highest_processed_.load()) {
    Ack(*frame);  // a re-send of a frame already tracked: the ack was lost
    return;
  }
  if (frame->frame_index <= highest_received_.load()) {
    if (frame->frame_index < highest_received_.load()) {
      // Older than one already queued: tracking it now would run time backwards.
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
  if (auto dropped = queue_.Push(std::move(frame))) {
    ++dropped_;
    TrackResult result;
    result.state = TrackingState::kSkipped;
    result.reason = TrackingReason::kDropped;
    result.detail = "tracker busy (real-time pacing)";
    Report(**dropped, result, 0.0f);
    Ack(**dropped);
  }
}

void TrackerService::Work() {
  while (true) {
    auto frame = queue_.Pop(std::chrono::milliseconds(100));
    if (!frame) {
      if (queue_.closed()) return;
      continue;
    }
    Process(**frame);
  }
}

void TrackerService::Process(const stitch::frame_t& frame) {
  const Stopwatch watch;
  TrackResult result;
  try {
    const cv::Mat image = DecodeImage(frame);
    if (!tracker_) {
      tracker_ = std::make_unique<FrameTracker>(FromMessage(frame.camera));
      STITCH_LOG(INFO) << "camera " << tracker_->camera().Describe();
    }
    result = tracker_->Track(image, frame.t_ns, frame.frame_index);
  } catch (const Error& e) {
    result.state = TrackingState::kSkipped;
    result.reason = TrackingReason::kUndecodableFrame;
    result.detail = e.what();
    STITCH_LOG(WARNING) << "frame " << frame.frame_index << " skipped: " << e.what();
  }
  const float ms = static_cast<float>(watch.ElapsedMs());
  highest_processed_ = frame.frame_index;
  ++tracked_;
  Report(frame, result, ms);
  Ack(frame);
}

void TrackerService::Report(const stitch::frame_t& frame, const TrackResult& result, float tracking_ms) {
  stitch::tracking_status_t status;
  status.frame_index = frame.frame_index;
  status.t_ns = frame.t_ns;
  status.state = ToMessageState(result.state);
  status.reason = ToMessageReason(result.reason);
  status.detail = result.detail;
  status.submap_id = result.submap_id;
  status.cam_from_submap = ToMessage(result.cam_from_submap.value_or(Rigid3d()));
  status.num_features = result.num_features;
  status.num_tracked_points = result.num_tracked_points;
  status.tracking_ms = tracking_ms;
  status.mapper_connected = false;
  publisher_->Publish(bus::Channel(publisher_->agent(), bus::kTrackingStatus), &status);
  if (record_.is_open()) {
    FrameRecord record;
    record.frame_index = frame.frame_index;
    record.t_ns = frame.t_ns;
    record.state = TrackingStateName(result.state);
    record.reason = static_cast<int>(result.reason);
    record.submap_id = result.submap_id;
    if (result.cam_from_submap) record.world_from_cam = result.cam_from_submap->Inverse();
    record.num_features = result.num_features;
    record.tracked_points = result.num_tracked_points;
    record.is_keyframe = result.is_keyframe;
    record.tracking_ms = tracking_ms;
    std::lock_guard<std::mutex> lock(record_mutex_);
    record_ << FormatFrameRecord(record);
  }
}

void TrackerService::Ack(const stitch::frame_t& frame) {
  stitch::frame_ack_t ack;
  ack.frame_index = frame.frame_index;
  ack.t_ns = frame.t_ns;
  publisher_->Publish(bus::Channel(publisher_->agent(), bus::kFrameAck), &ack);
}

}  // namespace stitch
