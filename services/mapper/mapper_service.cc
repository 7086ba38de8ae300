#include "services/mapper/mapper_service.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include "services/common/map_convert.h"
#include "stitch/io/ply.h"
#include "stitch/link_status_t.hpp"
#include "stitch/records/keyframe_record.h"
#include "stitch/submap_request_t.hpp"
#include "stitch/tracking_status_t.hpp"
#include "stitch/util/log.h"
#include "stitch/util/options.h"
#include "stitch/util/time.h"

namespace stitch {

namespace {
// A link bridge's backlog beyond a day is not a backlog but a forged or corrupt LINK_STATUS.
constexpr double kMaxLinkBacklogS = 86400;
}  // namespace

MapperService::MapperService(lcm::LCM* lcm, bus::Publisher* publisher, MapperOptions options, const OrbOptions& orb,
                             const Vocabulary* vocabulary, std::string record_dir)
    : publisher_(publisher),
      options_(std::move(options)),
      orb_(orb),
      pyramid_(ScalePyramid::From(orb)),
      vocabulary_(vocabulary),
      record_dir_(std::move(record_dir)),
      subscriber_(lcm),
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
        if (!(status->backlog_s >= 0 && status->backlog_s <= kMaxLinkBacklogS)) {
          subscriber_.Reject(channel, "says the link is " + std::to_string(status->backlog_s) + " s behind (0-" +
                                          std::to_string(static_cast<int>(kMaxLinkBacklogS)) + " s is plausible)");
          return;
        }
        link_backlog_s_ = status->backlog_s;
        link_budget_ = std::isfinite(status->budget_bytes_per_s) && status->budget_bytes_per_s > 0
                           ? status->budget_bytes_per_s
                           : 0.0;
        bytes_since_link_status_ = 0;
        link_status_at_ = MonotonicSeconds();
      });
  // The merger asks again for what the link lost.
  subscriber_.Subscribe<stitch::submap_request_t>(
      bus::Channel(publisher_->agent(), bus::kSubmapRequest),
      [this](std::unique_ptr<stitch::submap_request_t> request, const std::string&) {
        last_request_at_ = MonotonicSeconds();
        merger_confirms_ = true;  // a merger that asks again also says when it holds a submap whole
        std::lock_guard<std::mutex> lock(requests_mutex_);
        if (request->complete && request->num_keyframes == 0 && !request->full_state) {
          // Bounded: ids come off the link (only the last submap's matters, when stopping).
          if (confirmed_complete_.size() >= 1024) confirmed_complete_.erase(confirmed_complete_.begin());
          confirmed_complete_.insert(SubmapId(request->submap_id));
          return;
        }
        Request& wanted = requests_[SubmapId(request->submap_id)];
        for (int64_t id : request->keyframe_ids) wanted.keyframes.insert(KeyframeId(id));
        wanted.full_state |= request->full_state;
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
      PublishSubmapUpdate(mapping_->MakeFinalSubmapUpdate(*closed), Sent::kFinalState);
    } else if (!mapping_->closed_maps().empty()) {
      last = mapping_->closed_maps().back()->id();
    }
    LingerForTheMerger(last);
  }
  if (points_thinned_ > 0) {
    STITCH_LOG(INFO) << "left " << points_thinned_ << " point refinements under "
                     << options_.submap_point_resend_fraction << " of their distance out of the submap updates";
  }
  if (keyframes_hurried_ > 0) {
    STITCH_LOG(INFO) << keyframes_hurried_.load() << " of " << mapped_.load()
                     << " keyframes had their adjustment cut short or left to the next keyframe, which was waiting";
  }
  LogSentBytes();
  if (keyframes_deferred_ > 0) {
    STITCH_LOG(INFO) << keyframes_deferred_
                     << " keyframes waited for the merger to ask for them: the link bridge was over "
                     << options_.link_backlog_defer_s << " s behind";
  }
  if (points_held_back_ > 0) {
    STITCH_LOG(INFO) << "held back " << points_held_back_ << " point refinements while the link had a backlog";
  }
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

void MapperService::LogSentBytes() const {
  static const char* kWhy[] = {"with their keyframes", "final states", "manifests", "sent again"};
  int64_t total = 0;
  std::ostringstream parts;
  for (size_t i = 0; i < sent_bytes_.size(); ++i) {
    const SentBytes& sent = sent_bytes_[i];
    total += sent.bytes;
    if (sent.messages == 0) continue;
    parts << (parts.tellp() > 0 ? "; " : "") << kWhy[i] << " " << sent.bytes / 1000 << " kB in " << sent.messages
          << " messages";
    if (sent.keyframes > 0) parts << " (" << sent.keyframes << " keyframes, " << sent.keyframe_bytes / 1000 << " kB)";
  }
  if (total > 0) {
    STITCH_LOG(INFO) << "sent " << total / 1000 << " kB of submap updates: " << parts.str();
  }
}

void MapperService::LingerForTheMerger(SubmapId last) {
  // The merger may still lack the last keyframes (lost on the way), or be busy refining its map
  // before it looks (seconds on a large map).
  // ...and every submap closed before it (behind a slow link the merger may still be asking for
  // their keyframes, or its word on one was lost). `last` is the newest of the closed submaps.
  const auto unconfirmed = [&] {
    std::vector<SubmapId> waiting;
    std::lock_guard<std::mutex> lock(requests_mutex_);
    for (const auto& closed : mapping_->closed_maps()) {
      if (!confirmed_complete_.count(closed->id())) waiting.push_back(closed->id());
    }
    return waiting;
  };
  const double start = MonotonicSeconds();
  double final_sent = start;
  double counting_from = start;  // the linger counts once the link bridge has caught up
  bool waited_for_link = false;
  double last_progress = start;
  while (last.valid()) {
    const double now = MonotonicSeconds();
    // A bridge still sending what the mapper sent: the merger cannot ask for it yet.
    const bool link_behind = LinkBacklogSeconds() > 1.0;
    if (link_behind && now - start < options_.stop_link_drain_s) {
      if (!waited_for_link) {
        STITCH_LOG(INFO) << "waiting for the link bridge (" << LinkBacklogSeconds()
                         << " s behind) before the merger's last requests, at most " << options_.stop_link_drain_s
                         << " s";
        last_progress = now;
      } else if (now - last_progress >= 15.0) {
        last_progress = now;
        size_t asked = 0;
        {
          std::lock_guard<std::mutex> lock(requests_mutex_);
          for (const auto& [submap, wanted] : requests_) asked += wanted.keyframes.size();
        }
        STITCH_LOG(INFO) << "still delivering to the ground (" << static_cast<int>(now - start)
                         << " s): the link bridge is " << LinkBacklogSeconds() << " s behind, " << asked
                         << " keyframes asked for wait, " << unconfirmed().size()
                         << " submaps not yet held whole by the merger";
      }
      waited_for_link = true;
      counting_from = now;
    }
    const std::vector<SubmapId> waiting = unconfirmed();
    if (now - counting_from >= options_.stop_linger_s) {
      if (merger_confirms_.load() && options_.stop_linger_s > 0 && !waiting.empty()) {
        std::string names;
        for (SubmapId id : waiting) names += (names.empty() ? "" : ", ") + SubmapName(id);
        STITCH_LOG(WARNING) << "stopping without the merger saying it holds submap" << (waiting.size() > 1 ? "s " : " ")
                            << names << " whole (waited " << options_.stop_linger_s << " s)";
      }
      break;
    }
    if (merger_confirms_.load()) {
      if (waiting.empty()) {
        STITCH_LOG(INFO) << "the merger holds every submap whole";
        break;
      }
      // A final state may be what was lost (or the merger's word on it): once more every 2 s
      // while nothing is asked, one submap at a time, the last first (not before what was sent
      // last has had the time to go out: ResendIfRequested holds it).
      if (now - final_sent > 2.0 && now - last_request_at_.load() > 2.0) {
        final_sent = now;
        std::lock_guard<std::mutex> lock(requests_mutex_);
        requests_[waiting.back()].full_state = true;
      }
    } else if (now - counting_from > 2.5 && now - last_request_at_.load() > 2.0) {
      STITCH_LOG(INFO) << "no request from a merger for 2 s: stopping";
      break;  // a merger that never confirms (or none)
    }
    ResendIfRequested();
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
}

void MapperService::Work() {
  while (true) {
    auto keyframe = queue_.Pop(std::chrono::milliseconds(20));
    if (keyframe) Process(**keyframe);
    if (queue_.size() == 0) CloseIfRequested();  // after the submap's queued keyframes
    ResendIfRequested();
    ReleaseHeldWhole();
    // Idle (the aircraft is not exploring): say once a second which keyframes the current submap
    // holds, so a merger that lost the newest one asks for it.
    const double now = MonotonicSeconds();
    if (keyframe) {
      last_activity_ = now;
    } else if (mapping_ && now - last_activity_ > 1.0) {
      last_activity_ = now;
      PublishSubmapUpdate(mapping_->MakeManifestUpdate(), Sent::kManifest);
    }
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
  if (const auto closed = mapping_->CloseSubmap())
    PublishSubmapUpdate(mapping_->MakeFinalSubmapUpdate(*closed), Sent::kFinalState);
}

void MapperService::ResendIfRequested() {
  std::map<SubmapId, Request> requests;
  {
    std::lock_guard<std::mutex> lock(requests_mutex_);
    requests.swap(requests_);
  }
  if (requests.empty() || !mapping_) return;
  const double now = MonotonicSeconds();
  const auto due = [now](const auto& holds, const auto& key) {
    const auto it = holds.find(key);
    return it == holds.end() || it->second <= now;
  };
  std::map<SubmapId, Request> later;  // not answered while the link bridge is far behind
  for (const auto& [submap, wanted] : requests) {
    if (!mapping_->Holds(submap)) continue;  // let go of, or never this mapper's (ids off the link)
    // Requests repeat until the merger has what it asked for: what was sent and has not had the
    // time to arrive is not sent again.
    std::vector<KeyframeId> keyframes;
    for (KeyframeId id : wanted.keyframes) {
      if (due(keyframe_resend_after_, id) && mapping_->Holds(id)) keyframes.push_back(id);
    }
    bool full_state = wanted.full_state && due(state_resend_after_, submap);
    if (keyframes.empty() && !full_state) continue;
    // Behind a link that carries less than the flight makes, what is queued behind the backlog
    // would wait there until it expires: answer in pieces, each once the backlog has gone out.
    size_t next = 0;
    while (next < keyframes.size() || full_state) {
      if (LinkDeferring()) {
        Request& rest = later[submap];
        rest.keyframes.insert(keyframes.begin() + static_cast<std::ptrdiff_t>(next), keyframes.end());
        rest.full_state |= full_state;
        break;
      }
      const size_t end = std::min(keyframes.size(), next + kKeyframesPerAnswer);
      const std::vector<KeyframeId> piece(keyframes.begin() + static_cast<std::ptrdiff_t>(next),
                                          keyframes.begin() + static_cast<std::ptrdiff_t>(end));
      next = end;
      const SubmapUpdate update = mapping_->MakeResendUpdate(submap, piece, full_state);
      if (!update.submap.valid()) break;
      PublishParts(update, Sent::kResend);
      HoldResends(update, full_state);
      ++resends_;
      STITCH_LOG(INFO) << "sent " << update.new_keyframes.size() << " keyframes of submap " << SubmapName(submap)
                       << (full_state ? " and its whole state" : "") << " again: the merger lacked them";
      full_state = false;
    }
  }
  if (later.empty()) return;
  std::lock_guard<std::mutex> lock(requests_mutex_);
  for (auto& [submap, rest] : later) {
    Request& wanted = requests_[submap];
    wanted.keyframes.insert(rest.keyframes.begin(), rest.keyframes.end());
    wanted.full_state |= rest.full_state;
  }
}

int MapperService::NewKeyframesWaiting() const {
  // A copy of a keyframe the mapper holds (sent again by a tracker tired of waiting for its
  // answer, or repeated by the link) is only answered: it is no work waiting.
  return static_cast<int>(queue_.CountIf(
      [this](const auto& waiting) { return !mapping_ || !mapping_->Holds(KeyframeId(waiting->keyframe_id)); }));
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
  hooks.new_points_made = [this](const LocalMapUpdate& update) {
    for (auto& part : ToMessages(update)) publisher_->Publish(bus::Channel(publisher_->agent(), bus::kLocalMap), &part);
  };
  MappedKeyframe mapped = mapping_->MapKeyframe(std::move(received.keyframe), received.new_points, hooks);
  const MappingReport& report = mapped.report;
  if (!report.duplicate) ++mapped_;
  if (report.deferred || report.bundle_adjustment.interrupted) ++keyframes_hurried_;
  if (mapped.closed_final) PublishSubmapUpdate(*mapped.closed_final, Sent::kFinalState);
  if (report.reopened_submap) {
    STITCH_LOG(INFO) << "submap " << SubmapName(*report.reopened_submap) << " reopened (the tracker relocalized in it)";
  }
  mapped.for_tracker.queued_keyframes = NewKeyframesWaiting();
  for (auto& part : ToMessages(mapped.for_tracker)) {
    publisher_->Publish(bus::Channel(publisher_->agent(), bus::kLocalMap), &part);
  }
  if (LinkDeferring()) {
    // Far behind: the keyframe waits for the merger to ask for it (the manifest says it exists;
    // small messages overtake the bridge's queue), so nothing queued there expires unsent.
    ++keyframes_deferred_;
    PublishSubmapUpdate(mapping_->MakeManifestUpdate(), Sent::kManifest);
  } else {
    ThinForTheLink(&mapped.for_merger);
    PublishSubmapUpdate(mapped.for_merger, Sent::kKeyframeUpdate);
  }
  STITCH_LOG(DEBUG) << "keyframe " << id << ": " << report.new_points << " new points, " << report.fused << " fused, "
                    << report.culled_points << " points and " << report.culled_keyframes.size()
                    << " keyframes culled, BA " << report.bundle_adjustment.initial_rms_px << " -> "
                    << report.bundle_adjustment.final_rms_px << " px, " << report.milliseconds << " ms";
}

void MapperService::ThinForTheLink(SubmapUpdate* update) {
  const double fraction = options_.submap_point_resend_fraction;
  const Map* map = mapping_ ? mapping_->map() : nullptr;
  if (!map) return;
  std::vector<MapPoint>& points = update->changes.points;
  // While the link is behind, refinements wait (for a later update or the final state at close).
  const bool congested = LinkCongested();
  if (congested != link_congested_) {
    link_congested_ = congested;
    STITCH_LOG(INFO) << (congested ? "the link bridge is " + std::to_string(link_backlog_s_.load()) +
                                         " s behind: submap updates carry new keyframes and points only"
                                   : std::string("the link has caught up: point refinements go again"));
  }
  const size_t before = points.size();
  points.erase(std::remove_if(points.begin(), points.end(),
                              [&](const MapPoint& point) {
                                const auto sent = sent_positions_.find(point.id);
                                if (sent == sent_positions_.end()) return false;
                                if (congested) {
                                  ++points_held_back_;
                                  return true;
                                }
                                if (!(fraction > 0)) return false;
                                const Keyframe* reference = map->FindKeyframe(point.reference_keyframe);
                                const double distance =
                                    reference ? (point.position - reference->Centre()).norm() : point.max_distance;
                                return (point.position - sent->second).norm() <= fraction * distance;
                              }),
               points.end());
  for (const MapPoint& point : points) sent_positions_[point.id] = point.position;
  if (!congested) points_thinned_ += static_cast<int64_t>(before - points.size());
  // A keyframe's associations go again only when they changed, and only when asked for.
  auto& associations = update->changes.associations;
  associations.erase(std::remove_if(associations.begin(), associations.end(),
                                    [&](const auto& association) {
                                      if (!options_.submap_window_associations) return true;
                                      size_t hash = association.second.size();
                                      for (MapPointId p : association.second) {
                                        hash = hash * 1000003u ^ std::hash<int64_t>()(p.value);
                                      }
                                      auto [it, fresh] = sent_associations_.try_emplace(association.first, hash);
                                      if (fresh || it->second != hash) {
                                        it->second = hash;
                                        return false;
                                      }
                                      return true;
                                    }),
                     associations.end());
}

double MapperService::LinkBacklogSeconds() const {
  // A bridge that stopped reporting (gone, or never there) is not waited for.
  if (MonotonicSeconds() - link_status_at_.load() >= 3.0) return 0.0;
  // What this mapper published since the bridge's report waits behind it (reports come at 1 Hz).
  const double budget = link_budget_.load();
  const double since = budget > 0 ? static_cast<double>(bytes_since_link_status_.load()) / budget : 0.0;
  return link_backlog_s_.load() + since;
}

bool MapperService::LinkDeferring() {
  const double limit = options_.link_backlog_defer_s;
  const bool deferring = limit > 0 && LinkBacklogSeconds() > limit;
  if (deferring != link_deferring_) {
    link_deferring_ = deferring;
    STITCH_LOG(INFO) << (deferring ? "the link bridge is " + std::to_string(LinkBacklogSeconds()) +
                                         " s behind: new keyframes and answers to the merger wait for it"
                                   : std::string("the link bridge is back under ") + std::to_string(limit) +
                                         " s behind: keyframes go again");
  }
  return deferring;
}

bool MapperService::LinkCongested() const {
  const double limit = options_.link_backlog_thin_s;
  return limit > 0 && LinkBacklogSeconds() > limit;
}

double MapperService::ResendHoldSeconds() const {
  // The backlog is bytes over the budget; the datagrams' headers and the repairs of a lossy link
  // take their share of the budget too, so what waits takes longer than that to go out.
  return 0.5 + std::clamp(1.5 * LinkBacklogSeconds(), 0.0, options_.resend_max_hold_s);
}

void MapperService::HoldResends(const SubmapUpdate& update, bool whole_state) {
  const double now = MonotonicSeconds();
  const double until = now + ResendHoldSeconds();
  if (keyframe_resend_after_.size() > 4096) {  // holds that have passed mean nothing: forget them
    for (auto it = keyframe_resend_after_.begin(); it != keyframe_resend_after_.end();) {
      it = it->second <= now ? keyframe_resend_after_.erase(it) : std::next(it);
    }
  }
  for (const Keyframe& keyframe : update.new_keyframes) keyframe_resend_after_[keyframe.id] = until;
  if (whole_state) state_resend_after_[update.submap] = until;
}

void MapperService::PublishParts(const SubmapUpdate& update, Sent why) {
  SentBytes& sent = sent_bytes_[static_cast<size_t>(why)];
  for (auto& part : ToMessages(update)) {
    const int64_t bytes = part.getEncodedSize();
    ++sent.messages;
    sent.bytes += bytes;
    for (const auto& keyframe : part.keyframes) {
      ++sent.keyframes;
      sent.keyframe_bytes += keyframe._getEncodedSizeNoHash();
    }
    publisher_->Publish(bus::Channel(publisher_->agent(), bus::kSubmap), &part);
    bytes_since_link_status_ += bytes;
  }
}

void MapperService::PublishSubmapUpdate(const SubmapUpdate& update, Sent why) {
  if (!update.submap.valid()) return;
  PublishParts(update, why);
  HoldResends(update, update.closed);
  if (update.closed) {
    STITCH_LOG(INFO) << "submap " << SubmapName(update.submap) << " closed: " << update.manifest.size()
                     << " keyframes, " << update.changes.points.size() << " points sent to the merger";
  }
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
  std::vector<SubmapId> release;
  {
    std::lock_guard<std::mutex> lock(requests_mutex_);
    for (const auto& closed : mapping_->closed_maps()) {
      if (SubmapNumber(closed->id()) < first_held && confirmed_complete_.count(closed->id())) {
        release.push_back(closed->id());
      }
    }
  }
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
    for (auto it = sent_positions_.begin(); it != sent_positions_.end();) {
      it = SubmapOf(it->first) == submap ? sent_positions_.erase(it) : std::next(it);
    }
    for (auto it = sent_associations_.begin(); it != sent_associations_.end();) {
      it = SubmapOf(it->first) == submap ? sent_associations_.erase(it) : std::next(it);
    }
    state_resend_after_.erase(submap);
    for (auto it = keyframe_resend_after_.begin(); it != keyframe_resend_after_.end();) {
      it = SubmapOf(it->first) == submap ? keyframe_resend_after_.erase(it) : std::next(it);
    }
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
  WritePly((std::filesystem::path(record_dir_) / "submaps.ply").string(), cloud);
  if (!released_.empty()) {
    std::error_code ignored;
    std::filesystem::remove(released_points_path(), ignored);
  }
  STITCH_LOG(INFO) << "wrote " << cloud.size() << " map points of " << maps.size() + released_.size() << " submaps to "
                   << record_dir_;
}

}  // namespace stitch
