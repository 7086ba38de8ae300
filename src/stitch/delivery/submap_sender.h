#pragma once
// The mapper's half of the submap delivery protocol (delivery.h): what goes to the merger, when,
// and what goes again. It thins each keyframe's update for the link (refined points that barely
// moved, associations unchanged), holds refinements back while the link bridge is behind and new
// keyframes while it is far behind (the manifest says they exist, so the merger asks later),
// answers the merger's requests once what was sent last had the time to cross the link's backlog,
// says which closed submaps the merger holds whole (the mapper may let them go), and at stop
// lingers until the merger holds every submap whole. No LCM: parts go out through a Transport.

#include <array>
#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <set>
#include <string>
#include <unordered_map>
#include <vector>

#include "stitch/delivery/delivery.h"
#include "stitch/map/submap_update.h"

namespace stitch {

// The settings of the sender (in the `mapper:` section of a stitch config, under its own keys).
struct SenderOptions {
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

  template <class Visitor>
  void VisitFields(Visitor& v) {
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
  }
  // `section` names the settings in the reason (e.g. "mapper").
  bool Check(const std::string& section, std::string* why) const;
};

// What the sender may send again: the mapper's submaps (LocalMapping in the mapper service).
class SubmapSource {
 public:
  virtual ~SubmapSource() = default;
  // The submap being mapped (null before the first keyframe).
  virtual const Map* current() const = 0;
  // Submaps closed and still held.
  virtual std::vector<SubmapId> closed() const = 0;
  virtual bool Holds(SubmapId submap) const = 0;
  virtual bool Holds(KeyframeId keyframe) const = 0;
  // Those of `keyframes` still held, and with `full_state` the submap's whole state
  // (LocalMapping::MakeResendUpdate); an empty update for a submap not held.
  virtual SubmapUpdate MakeResendUpdate(SubmapId submap, const std::vector<KeyframeId>& keyframes, bool full_state) = 0;
  // The current submap's manifest alone (LocalMapping::MakeManifestUpdate).
  virtual SubmapUpdate MakeManifestUpdate() = 0;
};

class SubmapSender {
 public:
  // What a part of an update cost on the wire, bytes (in all, and for its keyframes).
  struct PartSent {
    int64_t bytes = 0, keyframe_bytes = 0;
  };
  // Sends part `index` of `count` of an update (the receiver's final state is whole once every
  // part of its revision has arrived).
  using Transport = std::function<PartSent(const SubmapUpdate& part, int32_t index, int32_t count)>;

  // `source` must outlive the sender. Updates go out in parts of about `max_part_bytes`.
  SubmapSender(SenderOptions options, SubmapSource* source, Transport transport, DeliveryClock clock = nullptr,
               size_t max_part_bytes = 60000);

  // From the other side; any thread.
  // The aircraft's link bridge: how far behind it is and its budget (0: none). False, with why,
  // for a backlog no link has (forged or corrupt): it is not believed.
  bool OnLinkStatus(double backlog_s, double budget_bytes_per_s, std::string* why);
  // The merger asks again for what the link lost, or says it holds a closed submap whole.
  void OnRequest(const DeliveryRequest& request);

  // The owner thread.
  // A new keyframe's update (the keyframe in full and the window's changes): thinned for the
  // link, or, while the link is far behind, only the current submap's manifest.
  void SendKeyframeUpdate(SubmapUpdate update);
  // A closed submap's final state, whole.
  void SendFinalState(const SubmapUpdate& update);
  // The current submap's manifest once a second while no keyframe comes (`keyframe_arrived`
  // says one did since the last call), so a merger that lost the newest keyframe asks for it.
  void SendManifestIfIdle(bool keyframe_arrived);
  // Answers the merger's requests: what it asked for and the sender still holds, not before what
  // was sent last has had the time to arrive; behind a far-behind link, in pieces later.
  void AnswerRequests();
  // Of `submaps`, those the merger said it holds whole.
  std::vector<SubmapId> HeldWhole(const std::vector<SubmapId>& submaps) const;
  // Forgets what was sent of a submap let go.
  void Forget(SubmapId submap);

  // On stop, after closing `last` (the newest closed submap; invalid: none): answers the
  // merger's requests until it says it holds `last` and every submap closed before it whole (at
  // most stop_linger_s once the link bridge has caught up, stop_link_drain_s at most before
  // that), or, from a merger that never says so, until it stays quiet. Call LingerStep about
  // every 20 ms until it returns false.
  void StartLinger(SubmapId last);
  bool LingerStep();

  // The link bridge's backlog, seconds, with what was sent since it last said so (0 while it
  // does not report).
  double LinkBacklogSeconds() const;
  int64_t resends() const;
  // The figures of the flight for the log: refinements thinned and held back, bytes by kind,
  // keyframes deferred.
  void LogSummary() const;

 private:
  enum class Kind { kKeyframeUpdate, kFinalState, kManifest, kResend, kCount };
  struct SentBytes {
    int64_t messages = 0, bytes = 0, keyframes = 0, keyframe_bytes = 0;
  };
  struct Request {
    std::set<KeyframeId> keyframes;
    bool full_state = false;
  };
  double Now() const { return clock_(); }
  void Send(const SubmapUpdate& update, Kind kind);
  void SendParts(const SubmapUpdate& update, Kind kind);
  // Leaves out refined points the merger already has close enough and associations it has.
  void ThinForTheLink(SubmapUpdate* update);
  bool LinkCongested() const;
  // More than link_backlog_defer_s behind: new keyframes and answers wait (logs when it changes).
  bool LinkDeferring();
  double ResendHoldSeconds() const;
  void HoldResends(const SubmapUpdate& update, bool whole_state);
  std::vector<SubmapId> Unconfirmed() const;  // closed submaps not held whole by the merger

  SenderOptions options_;
  SubmapSource* source_;
  Transport transport_;
  DeliveryClock clock_;
  size_t max_part_bytes_;
  // From the other side (inbox_mutex_).
  mutable std::mutex inbox_mutex_;
  std::map<SubmapId, Request> requests_;   // from the merger
  std::set<SubmapId> confirmed_complete_;  // closed submaps the merger said it holds whole
  double last_request_at_ = -1e9;          // the merger's last request
  bool merger_confirms_ = false;           // a merger has said it holds a closed submap whole
  double link_backlog_s_ = 0, link_status_at_ = -1e9, link_budget_ = 0;
  int64_t bytes_since_link_status_ = 0;  // sent since the bridge's last report
  int64_t resends_ = 0;
  // The owner thread's.
  std::unordered_map<MapPointId, Eigen::Vector3d> sent_positions_;  // what the merger was last sent
  std::unordered_map<KeyframeId, size_t> sent_associations_;        // (a hash of each keyframe's)
  // When each keyframe and each submap's whole state may be sent again.
  std::map<KeyframeId, double> keyframe_resend_after_;
  std::map<SubmapId, double> state_resend_after_;
  double last_activity_ = 0;  // the last keyframe or manifest sent
  bool link_congested_ = false, link_deferring_ = false;
  int64_t points_thinned_ = 0, points_held_back_ = 0, keyframes_deferred_ = 0;
  std::array<SentBytes, static_cast<size_t>(Kind::kCount)> sent_bytes_{};
  // The linger at stop.
  struct Linger {
    SubmapId last;
    double start = 0, final_sent = 0, counting_from = 0, last_progress = 0;
    bool waited_for_link = false;
  } linger_;
};

}  // namespace stitch
