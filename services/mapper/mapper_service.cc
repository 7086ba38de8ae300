#include "services/mapper/mapper_service.h"

#include <filesystem>
#include <fstream>

#include "services/common/convert.h"
#include "services/common/map_convert.h"
#include "stitch/io/output_frames.h"
#include "stitch/io/ply.h"
#include "stitch/link_status_t.hpp"
#include "stitch/records/keyframe_record.h"
#include "stitch/submap_request_t.hpp"
#include "stitch/tracking_status_t.hpp"
#include "stitch/util/log.h"
#include "stitch/util/options.h"
#include "stitch/util/time.h"

namespace stitch {

const Map* MapperService::MappingSource::current() const {
  return *mapping_ ? (*mapping_)->map() : nullptr;
}

std::vector<SubmapId> MapperService::MappingSource::closed() const {
  std::vector<SubmapId> ids;
  if (*mapping_) {
    for (const auto& map : (*mapping_)->closed_maps()) ids.push_back(map->id());
  }
  return ids;
}

bool MapperService::MappingSource::Holds(SubmapId submap) const {
  return *mapping_ && (*mapping_)->Holds(submap);
}

bool MapperService::MappingSource::Holds(KeyframeId keyframe) const {
  return *mapping_ && (*mapping_)->Holds(keyframe);
}

SubmapUpdate MapperService::MappingSource::MakeResendUpdate(SubmapId submap, const std::vector<KeyframeId>& keyframes,
                                                            bool full_state) {
  return *mapping_ ? (*mapping_)->MakeResendUpdate(submap, keyframes, full_state) : SubmapUpdate();
}

SubmapUpdate MapperService::MappingSource::MakeManifestUpdate() {
  return *mapping_ ? (*mapping_)->MakeManifestUpdate() : SubmapUpdate();
}

MapperService::MapperService(lcm::LCM* lcm, bus::Publisher* publisher, MapperOptions options, const OrbOptions& orb,
                             const Vocabulary* vocabulary, std::string record_dir)
    : publisher_(publisher),
      options_(std::move(options)),
      orb_(orb),
      pyramid_(ScalePyramid::From(orb)),
      vocabulary_(vocabulary),
      record_dir_(std::move(record_dir)),
      sender_(options_.delivery, &source_,
              [this](const SubmapUpdate& part, int32_t index, int32_t count) {
                stitch::submap_update_t message = ToMessage(part, index, count);
                SubmapSender::PartSent sent;
                sent.bytes = message.getEncodedSize();
                for (const auto& keyframe : message.keyframes) sent.keyframe_bytes += keyframe._getEncodedSizeNoHash();
                publisher_->Publish(bus::Channel(publisher_->agent(), bus::kSubmap), &message);
                return sent;
              }),
      subscriber_(lcm, publisher->authenticator()),
      queue_(static_cast<size_t>(options_.max_queued_keyframes),
             BoundedQueue<std::unique_ptr<stitch::keyframe_t>>::WhenFull::kDropOldest) {
  CheckOptions(options_, "mapper");
  if (!vocabulary_ || vocabulary_->empty()) throw Error("the mapper needs a vocabulary");
  subscriber_.Subscribe<stitch::keyframe_t>(bus::Channel(publisher_->agent(), bus::kKeyframe),
                                            [this](std::unique_ptr<stitch::keyframe_t> keyframe, const std::string&) {
                                              ++received_;
                                              {
                                                std::lock_guard<std::mutex> lock(tracker_mutex_);
                                                keyframe_session_ = keyframe->header.sender_session;
                                              }
                                              if (auto dropped = queue_.Push(std::move(keyframe))) {
                                                ++rejected_;
                                                STITCH_LOG(WARNING) << "mapper queue full: dropped keyframe "
                                                                    << (*dropped)->keyframe_id;
                                              }
                                            });
  // The tracker closes a submap on loss; its status says so (submaps_closed goes up), and the
  // submap's final state goes to the merger at once. A lost status only delays this until the
  // next submap's first keyframe arrives.
  subscriber_.Subscribe<stitch::tracking_status_t>(
      bus::Channel(publisher_->agent(), bus::kTrackingStatus),
      [this](std::unique_ptr<stitch::tracking_status_t> status, const std::string& channel) {
        std::lock_guard<std::mutex> lock(tracker_mutex_);
        // Only the tracker whose keyframes the mapper maps closes its submaps: a status from
        // another session (forged, or a tracker that has sent no keyframe yet) closes nothing.
        if (keyframe_session_ != 0 && status->header.sender_session != keyframe_session_) {
          subscriber_.Reject(channel, "comes from session " + std::to_string(status->header.sender_session) +
                                          ", not that of the tracker whose keyframes are mapped");
          return;
        }
        tracker_first_held_ = status->first_submap_held;
        if (status->header.sender_session != tracker_session_) {
          tracker_session_ = status->header.sender_session;  // a (re)started tracker counts from 0
          tracker_submaps_closed_ = status->submaps_closed;
          return;
        }
        if (status->submaps_closed > tracker_submaps_closed_) {
          tracker_submaps_closed_ = status->submaps_closed;
          // A status tracking in its submap says nothing about which one was closed (the one
          // that did was lost on the way): that one closes when the next submap's keyframe comes.
          if (status->state != stitch::tracking_status_t::STATE_OK) close_requested_ = status->submap_id;
        }
      });
  // The aircraft's link bridge says how far behind it is.
  subscriber_.Subscribe<stitch::link_status_t>(
      bus::Channel(publisher_->agent(), bus::kLinkStatus),
      [this](std::unique_ptr<stitch::link_status_t> status, const std::string& channel) {
        std::string why;
        if (!sender_.OnLinkStatus(status->backlog_s, status->budget_bytes_per_s, &why))
          subscriber_.Reject(channel, why);
      });
  // The merger asks again for what the link lost, or says it holds a submap whole.
  subscriber_.Subscribe<stitch::submap_request_t>(
      bus::Channel(publisher_->agent(), bus::kSubmapRequest),
      [this](std::unique_ptr<stitch::submap_request_t> request, const std::string&) {
        sender_.OnRequest(FromMessage(*request));
      });
  heartbeat_ = std::make_unique<Heartbeat>(publisher_, "mapper", [this] {
    return Heartbeat::Counts{received_.load(), mapped_.load(), subscriber_.rejected() + rejected_.load()};
  });
}

MapperService::~MapperService() {
  Stop();
}

void MapperService::Start() {
  if (running_.exchange(true)) return;
  worker_ = std::thread([this] { Work(); });
  heartbeat_->Start();
  heartbeat_->SetState(stitch::service_status_t::STATE_RUNNING);
}

void MapperService::Stop() {
  if (!running_.exchange(false)) return;
  queue_.Close();
  if (worker_.joinable()) worker_.join();
  if (mapping_) {
    SubmapId last;
    if (const auto closed = mapping_->CloseSubmap()) {
      last = *closed;
      sender_.SendFinalState(mapping_->MakeFinalSubmapUpdate(*closed));
    } else if (!mapping_->closed_maps().empty()) {
      last = mapping_->closed_maps().back()->id();
    }
    sender_.StartLinger(last);
    while (sender_.LingerStep()) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  if (keyframes_hurried_ > 0) {
    STITCH_LOG(INFO) << keyframes_hurried_.load() << " of " << mapped_.load()
                     << " keyframes had their adjustment cut short or left to the next keyframe, which was waiting";
  }
  sender_.LogSummary();
  if (!record_dir_.empty()) {
    try {
      WriteRecords();
    } catch (const Error& e) {
      STITCH_LOG(ERROR) << "writing the map failed: " << e.what();
    }
  }
  heartbeat_->SetState(stitch::service_status_t::STATE_FINISHED);
  heartbeat_->Stop();
}

void MapperService::Work() {
  while (true) {
    auto keyframe = queue_.Pop(std::chrono::milliseconds(20));
    if (keyframe) Process(**keyframe);
    if (queue_.size() == 0) CloseIfRequested();  // after the submap's queued keyframes
    sender_.AnswerRequests();
    ReleaseHeldWhole();
    // Idle (the aircraft is not exploring): the current submap's manifest once a second.
    sender_.SendManifestIfIdle(keyframe.has_value());
    if (!keyframe && queue_.closed()) return;
  }
}

void MapperService::CloseIfRequested() {
  int64_t requested;
  {
    std::lock_guard<std::mutex> lock(tracker_mutex_);
    requested = close_requested_;
    close_requested_ = -1;
  }
  if (requested < 0 || !mapping_ || !mapping_->map() || mapping_->map()->id().value != requested) return;
  if (const auto closed = mapping_->CloseSubmap()) sender_.SendFinalState(mapping_->MakeFinalSubmapUpdate(*closed));
}

int MapperService::NewKeyframesWaiting() const {
  // A copy of a keyframe the mapper holds (sent again by a tracker tired of waiting for its
  // answer, or repeated by the link) is only answered: it is no work waiting.
  return static_cast<int>(queue_.CountIf(
      [this](const auto& waiting) { return !mapping_ || !mapping_->Holds(KeyframeId(waiting->keyframe_id)); }));
}

void MapperService::PublishLocalMap(const LocalMapUpdate& update) {
  for (auto& part : ToMessages(update)) publisher_->Publish(bus::Channel(publisher_->agent(), bus::kLocalMap), &part);
}

void MapperService::Process(const stitch::keyframe_t& message) {
  ReceivedKeyframe received;
  try {
    received = FromMessage(message, pyramid_);
  } catch (const Error& e) {
    ++rejected_;
    STITCH_LOG(WARNING) << "rejected a keyframe: " << e.what();
    return;
  }
  if (!mapping_) {
    mapping_ = std::make_unique<LocalMapping>(options_.mapping, received.camera, orb_, vocabulary_);
    STITCH_LOG(INFO) << "camera " << received.camera.Describe();
  }
  const KeyframeId id = received.keyframe.id;
  if (released_.count(SubmapOf(id))) {
    ++rejected_;
    STITCH_LOG(WARNING) << "refused keyframe " << IndexOf(id) << " of submap " << SubmapName(SubmapOf(id))
                        << ": that submap was let go (the tracker had dropped it and the merger holds it whole)";
    return;
  }
  MappingHooks hooks;
  // A new keyframe waiting behind this one cuts its adjustment short (the tracker is ahead).
  hooks.next_waiting = [this] { return NewKeyframesWaiting() > 0; };
  // The tracker gets the new points before the adjustment (it may not be waiting for it).
  hooks.new_points_made = [this](const LocalMapUpdate& update) { PublishLocalMap(update); };
  MappedKeyframe mapped = mapping_->MapKeyframe(std::move(received.keyframe), received.new_points, hooks);
  const MappingReport& report = mapped.report;
  if (!report.duplicate) ++mapped_;
  if (report.deferred || report.bundle_adjustment.interrupted) ++keyframes_hurried_;
  if (mapped.closed_final) sender_.SendFinalState(*mapped.closed_final);
  if (report.reopened_submap) {
    STITCH_LOG(INFO) << "submap " << SubmapName(*report.reopened_submap) << " reopened (the tracker relocalized in it)";
  }
  mapped.for_tracker.queued_keyframes = NewKeyframesWaiting();
  PublishLocalMap(mapped.for_tracker);
  sender_.SendKeyframeUpdate(std::move(mapped.for_merger));
  STITCH_LOG(DEBUG) << "keyframe " << id << ": " << report.new_points << " new points, " << report.fused << " fused, "
                    << report.culled_points << " points and " << report.culled_keyframes.size()
                    << " keyframes culled, BA " << report.bundle_adjustment.initial_rms_px << " -> "
                    << report.bundle_adjustment.final_rms_px << " px, " << report.milliseconds << " ms";
}

namespace {

// One colour per submap in submaps.ply.
ColouredPoint SubmapColoured(const Eigen::Vector3d& position, SubmapId submap) {
  static const uint8_t kPalette[][3] = {{30, 90, 200}, {220, 40, 40}, {40, 160, 40}, {180, 40, 180},  {220, 150, 20},
                                        {0, 140, 140}, {160, 60, 90}, {200, 110, 0}, {100, 100, 100}, {180, 180, 60}};
  const uint8_t* colour = kPalette[SubmapNumber(submap) % 10];
  ColouredPoint p;
  p.position = position.cast<float>();
  p.red = colour[0];
  p.green = colour[1];
  p.blue = colour[2];
  return p;
}

}  // namespace

std::string MapperService::released_points_path() const {
  return (std::filesystem::path(record_dir_) / ".released_points.bin").string();
}

void MapperService::ReleaseHeldWhole() {
  if (!mapping_) return;
  int first_held;
  {
    std::lock_guard<std::mutex> lock(tracker_mutex_);
    first_held = tracker_first_held_;
  }
  std::vector<SubmapId> dropped;  // by the tracker
  for (const auto& closed : mapping_->closed_maps()) {
    if (SubmapNumber(closed->id()) < first_held) dropped.push_back(closed->id());
  }
  const std::vector<SubmapId> release = sender_.HeldWhole(dropped);
  for (SubmapId submap : release) {
    LocalMapping::Released released = mapping_->ReleaseClosed(submap);
    if (!released.map) continue;
    const Map& map = *released.map;
    for (const auto& [id, keyframe] : map.keyframes()) {
      released_keyframes_.push_back({id.value, submap.value, keyframe.frame_index, keyframe.t_ns, /*culled=*/false,
                                     keyframe.cam_from_world.Inverse()});
    }
    for (const CulledKeyframe& culled : released.culled) {
      released_keyframes_.push_back({culled.id.value, submap.value, culled.frame_index, culled.t_ns, /*culled=*/true,
                                     culled.cam_from_world.Inverse()});
    }
    if (!record_dir_.empty()) {
      try {
        std::filesystem::create_directories(record_dir_);
        // (the first submap let go starts the file afresh: one left by an earlier run is not this one's)
        std::ofstream out(released_points_path(),
                          std::ios::binary | (released_.empty() ? std::ios::trunc : std::ios::app));
        for (const auto& [id, point] : map.points()) {
          const ColouredPoint p = SubmapColoured(point.position, submap);
          out.write(reinterpret_cast<const char*>(&p), sizeof(p));
        }
        if (!out) throw Error(released_points_path() + ": cannot write");
      } catch (const std::exception& e) {
        STITCH_LOG(ERROR) << "the points of submap " << SubmapName(submap)
                          << " are not kept for submaps.ply: " << e.what();
      }
    }
    sender_.Forget(submap);
    released_.insert(submap);
    ++released_count_;
    STITCH_LOG(INFO) << "submap " << SubmapName(submap) << " let go (" << map.num_keyframes() << " keyframes, "
                     << map.num_points() << " points): the merger holds it whole and the tracker has dropped it";
  }
}

void MapperService::WriteRecords() const {
  std::filesystem::create_directories(record_dir_);
  std::vector<const Map*> maps;
  if (mapping_) {
    for (const auto& closed : mapping_->closed_maps()) maps.push_back(closed.get());
    if (mapping_->map()) maps.push_back(mapping_->map());
  }
  std::vector<ColouredPoint> cloud;
  std::vector<KeyframeRecord> keyframes = released_keyframes_;
  if (!released_.empty()) {
    std::ifstream in(released_points_path(), std::ios::binary);
    for (ColouredPoint p; in.read(reinterpret_cast<char*>(&p), sizeof(p));) cloud.push_back(p);
  }
  for (size_t m = 0; m < maps.size(); ++m) {
    for (const auto& [id, point] : maps[m]->points()) cloud.push_back(SubmapColoured(point.position, maps[m]->id()));
    for (const auto& [id, keyframe] : maps[m]->keyframes()) {
      keyframes.push_back({id.value, maps[m]->id().value, keyframe.frame_index, keyframe.t_ns, /*culled=*/false,
                           keyframe.cam_from_world.Inverse()});
    }
  }
  for (const auto& culled : mapping_ ? mapping_->CulledKeyframePoses() : std::vector<CulledKeyframe>()) {
    keyframes.push_back({culled.id.value, SubmapOf(culled.id).value, culled.frame_index, culled.t_ns, /*culled=*/true,
                         culled.cam_from_world.Inverse()});
  }
  WriteKeyframeRecords((std::filesystem::path(record_dir_) / "keyframes.tsv").string(), keyframes);
  WritePly((std::filesystem::path(record_dir_) / "submaps.ply").string(), cloud, output_frames::kEachSubmap);
  if (!released_.empty()) {
    std::error_code ignored;
    std::filesystem::remove(released_points_path(), ignored);
  }
  STITCH_LOG(INFO) << "wrote " << cloud.size() << " map points of " << maps.size() + released_.size() << " submaps to "
                   << record_dir_;
}

}  // namespace stitch
