#pragma once
// Settings of the mapper service (the `mapper:` section of a stitch config).

#include <string>

#include "stitch/mapping/mapping_options.h"

namespace stitch {

struct MapperOptions {
  int max_queued_keyframes = 200;  // beyond this the oldest waiting keyframe is dropped (and logged)
  // Submap updates to the merger (over the link) carry a refined point again only when it moved
  // by more than this fraction of its distance from its reference keyframe (new points always; the
  // final state at close carries every point). 0: every refined point of the window, every time.
  double submap_point_resend_fraction = 0.01;
  // Whether a keyframe's submap update also carries the window keyframes' changed associations
  // (about 4 kB each, re-sent as points are added); without them the merger learns them from the
  // final state at close (the new keyframe always carries its own).
  bool submap_window_associations = false;
  // While the aircraft's link bridge reports more than this many seconds of backlog (its budget
  // is exceeded), submap updates carry only new keyframes and new points; refined points wait
  // for a later update or the final state at close. 0: never hold back.
  double link_backlog_thin_s = 2.0;
  // While it reports more than this many seconds (below link.max_queue_s, past which the bridge
  // drops what waits), new keyframes are not sent (the manifest lists them, so the merger asks)
  // and the merger's requests are answered only once the backlog falls below it again, a few
  // keyframes at a time: the flight's data then waits on the aircraft, not in the bridge's queue
  // where it would expire. Final states always go. 0: never wait.
  double link_backlog_defer_s = 20.0;
  // On stop, after the final state: answer the merger's requests for what the link lost until it
  // says it holds every submap whole (a merger that never says so: until none has come for
  // 2 s), at most this long (0: stop at once).
  double stop_linger_s = 10.0;
  // On stop, while the aircraft's link bridge reports a backlog (what the mapper sent has not
  // reached the ground yet, or keyframes still wait for a link that carries less than the flight
  // made: link_backlog_defer_s), stop_linger_s waits for the bridge to catch up, at most this
  // many seconds more. A 100 kB/s link takes about 2 minutes after a 40 s survey.
  double stop_link_drain_s = 300.0;
  // What was sent cannot reach the ground before the link bridge's backlog has gone out, so a
  // keyframe or a submap's whole state is sent again (the merger asks until it holds it) only
  // that long after it was last sent, at most this many seconds (the bridge drops what waited
  // longer than link.max_queue_s: then it is lost, and sent again) and at least half a second.
  double resend_max_hold_s = 60.0;
  MappingOptions mapping;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("max_queued_keyframes", max_queued_keyframes, "keyframes that may wait for the mapper");
    v("submap_point_resend_fraction", submap_point_resend_fraction,
      "send a refined point to the merger again only when it moved by more than this fraction of its distance to "
      "its reference keyframe (0: always)");
    v("submap_window_associations", submap_window_associations,
      "send the window keyframes' changed associations with every submap update (else at close only)");
    v("link_backlog_thin_s", link_backlog_thin_s,
      "while the link bridge is more than this many seconds behind, send new keyframes and points only (0: never)");
    v("link_backlog_defer_s", link_backlog_defer_s,
      "while the link bridge is more than this many seconds behind, new keyframes wait for the merger to ask for "
      "them and its requests wait for the backlog to fall (0: never)");
    v("stop_linger_s", stop_linger_s,
      "on stop, keep answering the merger's requests until it says it holds every submap whole (from a merger that "
      "never says so: until none came for 2 s), at most this long");
    v("stop_link_drain_s", stop_link_drain_s,
      "on stop, while the link bridge is behind, wait for it to catch up before stop_linger_s counts, at most this "
      "many seconds more");
    v("resend_max_hold_s", resend_max_hold_s,
      "a keyframe or a submap's whole state is sent again at the merger's request only once the link bridge's "
      "backlog at its last sending has gone out, at most this many seconds later (link.max_queue_s)");
    v("mapping", mapping, "the local mapping algorithm");
  }
  bool Check(std::string* why) const {
    if (max_queued_keyframes < 1) {
      if (why) *why = "mapper.max_queued_keyframes must be >= 1";
      return false;
    }
    if (!(submap_point_resend_fraction >= 0)) {
      if (why) *why = "mapper.submap_point_resend_fraction must be >= 0";
      return false;
    }
    if (!(stop_linger_s >= 0)) {
      if (why) *why = "mapper.stop_linger_s must be >= 0";
      return false;
    }
    if (!(stop_link_drain_s >= 0 && stop_link_drain_s <= 3600)) {
      if (why) *why = "mapper.stop_link_drain_s must be between 0 and 3600";
      return false;
    }
    if (!(resend_max_hold_s >= 0 && resend_max_hold_s <= 3600)) {
      if (why) *why = "mapper.resend_max_hold_s must be between 0 and 3600";
      return false;
    }
    if (!(link_backlog_defer_s >= 0 && link_backlog_defer_s <= 3600)) {
      if (why) *why = "mapper.link_backlog_defer_s must be between 0 and 3600";
      return false;
    }
    if (!(link_backlog_thin_s >= 0)) {
      if (why) *why = "mapper.link_backlog_thin_s must be >= 0";
      return false;
    }
    return mapping.Check(why);
  }
};

}  // namespace stitch
