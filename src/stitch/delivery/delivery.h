#pragma once
// The submap delivery protocol between a mapper (the aircraft) and a merger (the ground), over a
// link that may lose, repeat, reorder and delay what it carries (docs/messages.md, "Updates of
// maps"). No LCM here: the mapper service carries SubmapSender's parts as <agent>/SUBMAP and
// the merger's DeliveryRequests as <agent>/SUBMAP_REQUEST; SubmapReceiver judges what arrived.
//   mapper -> merger: each keyframe's update, thinned for the link; a closed submap's final
//     state (in parts, the first with the manifest); manifests while idle or deferring.
//   merger -> mapper: the keyframes a manifest lists and never arrived, a final state missing a
//     part or never sent, and "held whole" for each closed submap received completely.
// The mapper sends again what was asked for once what it sent last had the time to cross the
// link's backlog, lets a closed submap go once held whole, and lingers at stop until the merger
// holds every submap whole.

#include <functional>
#include <vector>

#include "stitch/util/ids.h"

namespace stitch {

// Seconds on a monotonic clock (MonotonicSeconds; tests inject their own).
using DeliveryClock = std::function<double()>;

// What a receiver asks of a sender about one submap.
struct DeliveryRequest {
  SubmapId submap;
  std::vector<KeyframeId> keyframes;  // listed by a manifest, never arrived
  bool full_state = false;            // the final state (or the whole state) again
  bool complete = false;              // nothing asked: the receiver holds the closed submap whole
};

}  // namespace stitch
