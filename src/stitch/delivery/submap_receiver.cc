#include "stitch/delivery/submap_receiver.h"

#include <algorithm>
#include <limits>

#include "stitch/util/log.h"
#include "stitch/util/time.h"

namespace stitch {

namespace {
// How far past an aircraft's newest revision an update may be: the mapper counts one revision per
// update it makes (a few per keyframe), and makes some the link never carries (thinned, lost).
// A jump may be this many, plus this many per second since the newest arrived.
constexpr int64_t kMaxRevisionJump = 1000;
constexpr int64_t kMaxRevisionsPerSecond = 100;
}  // namespace

SubmapReceiver::SubmapReceiver(ReceiverOptions options, DeliveryClock clock)
    : options_(options), clock_(clock ? std::move(clock) : DeliveryClock(MonotonicSeconds)) {}

bool SubmapReceiver::PlausibleRevision(const std::string& agent, int64_t revision, std::string* why) {
  const double now = Now();
  const auto newest = newest_revision_.find(agent);
  int64_t allowed = std::numeric_limits<int32_t>::max();
  if (newest != newest_revision_.end()) {
    const double waited_s = std::max(0.0, now - newest->second.heard_at);
    allowed = newest->second.revision + kMaxRevisionJump +
              static_cast<int64_t>(std::min(waited_s, 1e7) * static_cast<double>(kMaxRevisionsPerSecond));
  }
  if (revision < 0 || revision > allowed) {
    // Stale from then on, every later real update of the submap would leave it as it was.
    *why = "jumps to revision " + std::to_string(revision) + " from " +
           (newest == newest_revision_.end() ? std::string("none") : std::to_string(newest->second.revision));
    return false;
  }
  if (newest == newest_revision_.end()) {
    newest_revision_[agent] = {revision, now};
  } else if (revision > newest->second.revision) {
    newest->second = {revision, now};
  }
  return true;
}

bool SubmapReceiver::Received(const SubmapUpdate& update, int32_t part, int32_t num_parts, const SubmapReplica* replica,
                              size_t missing) {
  last_update_[update.submap] = Now();
  // A final state comes in parts, the first with the manifest and the removals: it is whole once
  // every part of its revision has arrived, in whatever order (its last part alone, arrived first
  // or with the first lost, left the merger judging the submap by an older manifest).
  bool final_state_whole = false;
  if (update.closed && update.full_state && part >= 0 && part < num_parts) {
    FinalStateParts& parts = final_parts_[update.submap];
    if (update.revision > parts.revision) parts = FinalStateParts{update.revision, num_parts, {}};
    if (update.revision == parts.revision && num_parts == parts.num_parts && parts.received.insert(part).second) {
      final_state_whole = static_cast<int32_t>(parts.received.size()) == parts.num_parts;
    }
  }
  if (missing > 0 && final_state_whole) {
    STITCH_LOG(WARNING) << "submap " << SubmapName(update.submap) << " closed with " << missing
                        << " keyframes never received (lost on the way"
                        << (options_.request_resends ? "; asking for them again)" : ")");
  }
  if (!replica || !replica->closed) {
    final_whole_.erase(update.submap);  // reopened (or not closed yet)
  } else if (final_state_whole) {
    final_whole_.insert(update.submap);
    confirmed_complete_.erase(update.submap);  // a final state sent again is confirmed again
  }
  return final_state_whole;
}

std::vector<DeliveryRequest> SubmapReceiver::Requests(const std::map<SubmapId, SubmapReplica>& replicas) {
  const double now = Now();
  std::vector<DeliveryRequest> requests;
  std::map<int, SubmapId> newest;  // per aircraft
  for (const auto& [id, replica] : replicas) {
    SubmapId& n = newest[AgentNumber(id)];
    if (!n.valid() || n < id) n = id;
  }
  int64_t missing_total = 0;
  std::map<KeyframeId, double> missing_since;
  for (const auto& [id, replica] : replicas) {
    if (IsSavedMap(id)) continue;  // read whole from a file (merger.prior_map): no mapper sends it
    DeliveryRequest request;
    request.submap = id;
    const size_t missing_before = missing_since.size();
    // The final state has arrived whole: what it lists and is not here was lost.
    const bool final_whole = replica.closed && final_whole_.count(id) > 0;
    for (KeyframeId kf : replica.manifest) {
      if (replica.map.FindKeyframe(kf)) continue;
      ++missing_total;
      // The parts of one update arrive within milliseconds: a keyframe is lost when it stays
      // missing for a while.
      const auto since = missing_since_.find(kf);
      const double first = since != missing_since_.end() ? since->second : now;
      missing_since[kf] = first;
      if (final_whole || now - first > 0.3 * options_.resend_interval_s) request.keyframes.push_back(kf);
    }
    if (options_.request_resends && final_whole && missing_since.size() == missing_before &&
        confirmed_complete_.insert(id).second) {
      // Nothing missing: the mapper, stopping, need not wait for more requests about it.
      DeliveryRequest complete;
      complete.submap = id;
      complete.complete = true;
      requests.push_back(complete);
      STITCH_LOG(INFO) << "holds submap " << SubmapName(id) << " whole (" << replica.manifest.size()
                       << " keyframes): told its mapper";
    }
    // Left open while a newer submap of its aircraft goes on, and quiet: its final state was lost
    // (a submap the tracker reopened is not quiet). Closed, but its final state never arrived in
    // all its parts, and quiet: a part was lost; asked for again, or its mapper would keep it
    // (never confirmed whole) and the merger its partial state, to the end of the flight.
    const auto heard = last_update_.find(id);
    const bool quiet = heard == last_update_.end() || now - heard->second > 3 * options_.resend_interval_s;
    request.full_state = quiet && (replica.closed ? !final_whole : newest[AgentNumber(id)] != id);
    if (!options_.request_resends || (request.keyframes.empty() && !request.full_state)) continue;
    double& last = last_request_.try_emplace(id, -1e9).first->second;
    if (now - last < options_.resend_interval_s) continue;
    last = now;
    requests.push_back(request);
    ++requests_made_;
    STITCH_LOG(INFO) << "asked for submap " << SubmapName(id) << " again: " << request.keyframes.size()
                     << " keyframes missing" << (request.full_state ? ", final state missing" : "");
  }
  keyframes_missing_ = missing_total;
  missing_since_.swap(missing_since);
  return requests;
}

}  // namespace stitch
