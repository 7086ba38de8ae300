#include "stitch/delivery/submap_sender.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "stitch/util/log.h"
#include "stitch/util/time.h"

namespace stitch {

namespace {
// A link bridge's backlog beyond a day is not a backlog but a forged or corrupt status.
constexpr double kMaxLinkBacklogS = 86400;
// Keyframes sent again in one piece behind a far-behind link: ~180 kB, under 2 s of a 100 kB/s link.
constexpr size_t kKeyframesPerAnswer = 4;
// Closed submaps remembered as held whole (ids come off the link; only the last matters at stop).
constexpr size_t kMaxConfirmed = 1024;
}  // namespace

bool SenderOptions::Check(const std::string& section, std::string* why) const {
  const auto fail = [&](const std::string& what) {
    if (why) *why = section + "." + what;
    return false;
  };
  if (!(submap_point_resend_fraction >= 0)) return fail("submap_point_resend_fraction must be >= 0");
  if (!(stop_linger_s >= 0)) return fail("stop_linger_s must be >= 0");
  if (!(stop_link_drain_s >= 0 && stop_link_drain_s <= 3600))
    return fail("stop_link_drain_s must be between 0 and 3600");
  if (!(resend_max_hold_s >= 0 && resend_max_hold_s <= 3600))
    return fail("resend_max_hold_s must be between 0 and 3600");
  if (!(link_backlog_defer_s >= 0 && link_backlog_defer_s <= 3600)) {
    return fail("link_backlog_defer_s must be between 0 and 3600");
  }
  if (!(link_backlog_thin_s >= 0)) return fail("link_backlog_thin_s must be >= 0");
  return true;
}

SubmapSender::SubmapSender(SenderOptions options, SubmapSource* source, Transport transport, DeliveryClock clock,
                           size_t max_part_bytes)
    : options_(options),
      source_(source),
      transport_(std::move(transport)),
      clock_(clock ? std::move(clock) : DeliveryClock(MonotonicSeconds)),
      max_part_bytes_(max_part_bytes) {}

bool SubmapSender::OnLinkStatus(double backlog_s, double budget_bytes_per_s, std::string* why) {
  if (!(backlog_s >= 0 && backlog_s <= kMaxLinkBacklogS)) {
    *why = "says the link is " + std::to_string(backlog_s) + " s behind (0-" +
           std::to_string(static_cast<int>(kMaxLinkBacklogS)) + " s is plausible)";
    return false;
  }
  std::lock_guard<std::mutex> lock(inbox_mutex_);
  link_backlog_s_ = backlog_s;
  link_budget_ = std::isfinite(budget_bytes_per_s) && budget_bytes_per_s > 0 ? budget_bytes_per_s : 0.0;
  bytes_since_link_status_ = 0;
  link_status_at_ = Now();
  return true;
}

void SubmapSender::OnRequest(const DeliveryRequest& request) {
  std::lock_guard<std::mutex> lock(inbox_mutex_);
  last_request_at_ = Now();
  merger_confirms_ = true;  // a merger that asks again also says when it holds a submap whole
  if (request.complete && request.keyframes.empty() && !request.full_state) {
    if (confirmed_complete_.size() >= kMaxConfirmed) confirmed_complete_.erase(confirmed_complete_.begin());
    confirmed_complete_.insert(request.submap);
    return;
  }
  Request& wanted = requests_[request.submap];
  wanted.keyframes.insert(request.keyframes.begin(), request.keyframes.end());
  wanted.full_state |= request.full_state;
}

double SubmapSender::LinkBacklogSeconds() const {
  std::lock_guard<std::mutex> lock(inbox_mutex_);
  // A bridge that stopped reporting (gone, or never there) is not waited for.
  if (Now() - link_status_at_ >= 3.0) return 0.0;
  // What was sent since the bridge's report waits behind it (reports come at 1 Hz).
  const double since = link_budget_ > 0 ? static_cast<double>(bytes_since_link_status_) / link_budget_ : 0.0;
  return link_backlog_s_ + since;
}

bool SubmapSender::LinkCongested() const {
  const double limit = options_.link_backlog_thin_s;
  return limit > 0 && LinkBacklogSeconds() > limit;
}

bool SubmapSender::LinkDeferring() {
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

double SubmapSender::ResendHoldSeconds() const {
  // The backlog is bytes over the budget; the datagrams' headers and the repairs of a lossy link
  // take their share of the budget too, so what waits takes longer than that to go out.
  return 0.5 + std::clamp(1.5 * LinkBacklogSeconds(), 0.0, options_.resend_max_hold_s);
}

void SubmapSender::HoldResends(const SubmapUpdate& update, bool whole_state) {
  const double now = Now();
  const double until = now + ResendHoldSeconds();
  if (keyframe_resend_after_.size() > 4096) {  // holds that have passed mean nothing: forget them
    for (auto it = keyframe_resend_after_.begin(); it != keyframe_resend_after_.end();) {
      it = it->second <= now ? keyframe_resend_after_.erase(it) : std::next(it);
    }
  }
  for (const Keyframe& keyframe : update.new_keyframes) keyframe_resend_after_[keyframe.id] = until;
  if (whole_state) state_resend_after_[update.submap] = until;
}

void SubmapSender::SendParts(const SubmapUpdate& update, Kind kind) {
  SentBytes& sent = sent_bytes_[static_cast<size_t>(kind)];
  const std::vector<SubmapUpdate> parts = SplitSubmapUpdate(update, max_part_bytes_);
  for (size_t p = 0; p < parts.size(); ++p) {
    const PartSent part = transport_(parts[p], static_cast<int32_t>(p), static_cast<int32_t>(parts.size()));
    ++sent.messages;
    sent.bytes += part.bytes;
    sent.keyframes += static_cast<int64_t>(parts[p].new_keyframes.size());
    sent.keyframe_bytes += part.keyframe_bytes;
    std::lock_guard<std::mutex> lock(inbox_mutex_);
    bytes_since_link_status_ += part.bytes;
  }
}

void SubmapSender::Send(const SubmapUpdate& update, Kind kind) {
  if (!update.submap.valid()) return;
  SendParts(update, kind);
  HoldResends(update, update.closed);
  if (update.closed) {
    STITCH_LOG(INFO) << "submap " << SubmapName(update.submap) << " closed: " << update.manifest.size()
                     << " keyframes, " << update.changes.points.size() << " points sent to the merger";
  }
}

void SubmapSender::SendFinalState(const SubmapUpdate& update) {
  Send(update, Kind::kFinalState);
}

void SubmapSender::SendKeyframeUpdate(SubmapUpdate update) {
  if (LinkDeferring()) {
    // Far behind: the keyframe waits for the merger to ask for it (the manifest says it exists;
    // small messages overtake the bridge's queue), so nothing queued there expires unsent.
    ++keyframes_deferred_;
    Send(source_->MakeManifestUpdate(), Kind::kManifest);
    return;
  }
  ThinForTheLink(&update);
  Send(update, Kind::kKeyframeUpdate);
}

void SubmapSender::SendManifestIfIdle(bool keyframe_arrived) {
  const double now = Now();
  if (keyframe_arrived) {
    last_activity_ = now;
  } else if (source_->current() && now - last_activity_ > 1.0) {
    last_activity_ = now;
    Send(source_->MakeManifestUpdate(), Kind::kManifest);
  }
}

void SubmapSender::ThinForTheLink(SubmapUpdate* update) {
  const double fraction = options_.submap_point_resend_fraction;
  const Map* map = source_->current();
  if (!map) return;
  std::vector<MapPoint>& points = update->changes.points;
  // While the link is behind, refinements wait (for a later update or the final state at close).
  const bool congested = LinkCongested();
  if (congested != link_congested_) {
    link_congested_ = congested;
    STITCH_LOG(INFO) << (congested ? "the link bridge is " + std::to_string(LinkBacklogSeconds()) +
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

void SubmapSender::AnswerRequests() {
  std::map<SubmapId, Request> requests;
  {
    std::lock_guard<std::mutex> lock(inbox_mutex_);
    requests.swap(requests_);
  }
  if (requests.empty()) return;
  const double now = Now();
  const auto due = [now](const auto& holds, const auto& key) {
    const auto it = holds.find(key);
    return it == holds.end() || it->second <= now;
  };
  std::map<SubmapId, Request> later;  // not answered while the link bridge is far behind
  for (const auto& [submap, wanted] : requests) {
    if (!source_->Holds(submap)) continue;  // let go of, or never this mapper's (ids off the link)
    // Requests repeat until the merger has what it asked for: what was sent and has not had the
    // time to arrive is not sent again.
    std::vector<KeyframeId> keyframes;
    for (KeyframeId id : wanted.keyframes) {
      if (due(keyframe_resend_after_, id) && source_->Holds(id)) keyframes.push_back(id);
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
      const SubmapUpdate update = source_->MakeResendUpdate(submap, piece, full_state);
      if (!update.submap.valid()) break;
      SendParts(update, Kind::kResend);
      HoldResends(update, full_state);
      {
        std::lock_guard<std::mutex> lock(inbox_mutex_);
        ++resends_;
      }
      STITCH_LOG(INFO) << "sent " << update.new_keyframes.size() << " keyframes of submap " << SubmapName(submap)
                       << (full_state ? " and its whole state" : "") << " again: the merger lacked them";
      full_state = false;
    }
  }
  if (later.empty()) return;
  std::lock_guard<std::mutex> lock(inbox_mutex_);
  for (auto& [submap, rest] : later) {
    Request& wanted = requests_[submap];
    wanted.keyframes.insert(rest.keyframes.begin(), rest.keyframes.end());
    wanted.full_state |= rest.full_state;
  }
}

std::vector<SubmapId> SubmapSender::HeldWhole(const std::vector<SubmapId>& submaps) const {
  std::vector<SubmapId> held;
  std::lock_guard<std::mutex> lock(inbox_mutex_);
  for (SubmapId id : submaps) {
    if (confirmed_complete_.count(id)) held.push_back(id);
  }
  return held;
}

void SubmapSender::Forget(SubmapId submap) {
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
}

std::vector<SubmapId> SubmapSender::Unconfirmed() const {
  std::vector<SubmapId> waiting;
  const std::vector<SubmapId> closed = source_->closed();
  std::lock_guard<std::mutex> lock(inbox_mutex_);
  for (SubmapId id : closed) {
    if (!confirmed_complete_.count(id)) waiting.push_back(id);
  }
  return waiting;
}

void SubmapSender::StartLinger(SubmapId last) {
  const double now = Now();
  linger_ = Linger{last, now, now, now, now, false};
}

bool SubmapSender::LingerStep() {
  // The merger may still lack the last keyframes (lost on the way), or be busy refining its map
  // before it looks (seconds on a large map); and every submap closed before the last (behind a
  // slow link the merger may still be asking for their keyframes, or its word on one was lost).
  Linger& l = linger_;
  if (!l.last.valid()) return false;
  const double now = Now();
  // A bridge still sending what the mapper sent: the merger cannot ask for it yet.
  const bool link_behind = LinkBacklogSeconds() > 1.0;
  if (link_behind && now - l.start < options_.stop_link_drain_s) {
    if (!l.waited_for_link) {
      STITCH_LOG(INFO) << "waiting for the link bridge (" << LinkBacklogSeconds()
                       << " s behind) before the merger's last requests, at most " << options_.stop_link_drain_s
                       << " s";
      l.last_progress = now;
    } else if (now - l.last_progress >= 15.0) {
      l.last_progress = now;
      size_t asked = 0;
      {
        std::lock_guard<std::mutex> lock(inbox_mutex_);
        for (const auto& [submap, wanted] : requests_) asked += wanted.keyframes.size();
      }
      STITCH_LOG(INFO) << "still delivering to the ground (" << static_cast<int>(now - l.start)
                       << " s): the link bridge is " << LinkBacklogSeconds() << " s behind, " << asked
                       << " keyframes asked for wait, " << Unconfirmed().size()
                       << " submaps not yet held whole by the merger";
    }
    l.waited_for_link = true;
    l.counting_from = now;
  }
  const std::vector<SubmapId> waiting = Unconfirmed();
  bool confirms;
  double last_request_at;
  {
    std::lock_guard<std::mutex> lock(inbox_mutex_);
    confirms = merger_confirms_;
    last_request_at = last_request_at_;
  }
  if (now - l.counting_from >= options_.stop_linger_s) {
    if (confirms && options_.stop_linger_s > 0 && !waiting.empty()) {
      std::string names;
      for (SubmapId id : waiting) names += (names.empty() ? "" : ", ") + SubmapName(id);
      STITCH_LOG(WARNING) << "stopping without the merger saying it holds submap" << (waiting.size() > 1 ? "s " : " ")
                          << names << " whole (waited " << options_.stop_linger_s << " s)";
    }
    return false;
  }
  if (confirms) {
    if (waiting.empty()) {
      STITCH_LOG(INFO) << "the merger holds every submap whole";
      return false;
    }
    // A final state may be what was lost (or the merger's word on it): once more every 2 s
    // while nothing is asked, one submap at a time, the last first (not before what was sent
    // last has had the time to go out: AnswerRequests holds it).
    if (now - l.final_sent > 2.0 && now - last_request_at > 2.0) {
      l.final_sent = now;
      std::lock_guard<std::mutex> lock(inbox_mutex_);
      requests_[waiting.back()].full_state = true;
    }
  } else if (now - l.counting_from > 2.5 && now - last_request_at > 2.0) {
    STITCH_LOG(INFO) << "no request from a merger for 2 s: stopping";
    return false;  // a merger that never confirms (or none)
  }
  AnswerRequests();
  return true;
}

int64_t SubmapSender::resends() const {
  std::lock_guard<std::mutex> lock(inbox_mutex_);
  return resends_;
}

void SubmapSender::LogSummary() const {
  if (points_thinned_ > 0) {
    STITCH_LOG(INFO) << "left " << points_thinned_ << " point refinements under "
                     << options_.submap_point_resend_fraction << " of their distance out of the submap updates";
  }
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
  if (keyframes_deferred_ > 0) {
    STITCH_LOG(INFO) << keyframes_deferred_
                     << " keyframes waited for the merger to ask for them: the link bridge was over "
                     << options_.link_backlog_defer_s << " s behind";
  }
  if (points_held_back_ > 0) {
    STITCH_LOG(INFO) << "held back " << points_held_back_ << " point refinements while the link had a backlog";
  }
}

}  // namespace stitch
