#pragma once
// The merger's half of the submap delivery protocol (delivery.h): it judges each part that
// arrives (a revision far past an aircraft's newest is refused; a closed submap's final state is
// whole once every part of its revision has arrived, in whatever order), and says what to ask
// the mapper for again: keyframes a manifest lists that stay missing, a final state missing a
// part or never sent while a newer submap goes on, and, once nothing is missing, that it holds a
// closed submap whole. No LCM: the merger service publishes its requests.

#include <cstdint>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "stitch/delivery/delivery.h"
#include "stitch/map/submap_update.h"

namespace stitch {

struct ReceiverOptions {
  bool request_resends = true;     // ask again for what was lost (merger.request_resends)
  double resend_interval_s = 1.0;  // between two requests about one submap (merger.resend_interval_s)
};

class SubmapReceiver {
 public:
  explicit SubmapReceiver(ReceiverOptions options, DeliveryClock clock = nullptr);

  // Whether an update numbered `revision` from `agent` is plausible: not negative, and not far
  // past that aircraft's newest (a forged 2^31-1 would make every later real update of its
  // submap look stale). A jump of 1000, plus 100 per second since the newest arrived, is. For
  // live updates (a journal or a recording holds no timing to judge by). False: why.
  bool PlausibleRevision(const std::string& agent, int64_t revision, std::string* why);

  // Part `part` of `num_parts` of `update` was applied; `replica` is its submap's copy after
  // (null if none), `missing` what its manifest lists and the copy lacks. Returns whether it
  // made the submap's final state whole.
  bool Received(const SubmapUpdate& update, int32_t part, int32_t num_parts, const SubmapReplica* replica,
                size_t missing);

  // What to ask for again, in order, given every submap's copy: for each submap, "held whole"
  // once (for a closed one whose final state arrived whole and lacks nothing), then a request
  // for what stays missing, at most once per resend_interval_s. Nothing with request_resends off.
  std::vector<DeliveryRequest> Requests(const std::map<SubmapId, SubmapReplica>& replicas);

  // Keyframes listed by manifests and not received, over every submap (at the last Requests).
  int64_t keyframes_missing() const { return keyframes_missing_; }
  int64_t requests_made() const { return requests_made_; }

 private:
  double Now() const { return clock_(); }

  ReceiverOptions options_;
  DeliveryClock clock_;
  struct NewestRevision {
    int64_t revision = 0;
    double heard_at = 0;
  };
  std::map<std::string, NewestRevision> newest_revision_;  // per aircraft
  struct FinalStateParts {
    int64_t revision = -1;
    int32_t num_parts = 0;
    std::set<int32_t> received;
  };
  std::map<SubmapId, FinalStateParts> final_parts_;  // each closed submap's newest final state, as it arrives
  std::set<SubmapId> final_whole_;                   // closed submaps whose final state arrived in all its parts
  std::set<SubmapId> confirmed_complete_;            // of those, the ones the mapper was told are held whole
  std::map<SubmapId, double> last_request_, last_update_;
  std::map<KeyframeId, double> missing_since_;  // listed by a manifest, not received
  int64_t keyframes_missing_ = 0, requests_made_ = 0;
};

}  // namespace stitch
