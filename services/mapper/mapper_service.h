#pragma once
// The mapper service: receives keyframes on <agent>/KEYFRAME, maps each with LocalMapping in its
// own worker thread, and publishes what changed on <agent>/LOCAL_MAP for the tracker and on
// <agent>/SUBMAP for the merger (each in parts of about 60 kB); a closed submap's final state
// goes out when the tracker reports the submap closed (<agent>/TRACKING_STATUS), else when the
// next submap's first keyframe arrives, or at Stop. A keyframe of a closed submap reopens it.
// When given a record folder it writes, at the end, submaps.ply (every submap's points in its own frame, one colour
// per submap) and keyframes.tsv (final keyframe poses, culled keyframes included).

#include <array>
#include <atomic>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <unordered_map>

#include "services/common/bus.h"
#include "services/common/service.h"
#include "services/mapper/mapper_options.h"
#include "stitch/keyframe_t.hpp"
#include "stitch/mapping/local_mapping.h"
#include "stitch/records/keyframe_record.h"
#include "stitch/util/bounded_queue.h"

namespace stitch {

class MapperService {
 public:
  // Subscribes at once: construct before the Dispatcher starts. `vocabulary` must outlive it.
  MapperService(lcm::LCM* lcm, bus::Publisher* publisher, MapperOptions options, const OrbOptions& orb,
                const Vocabulary* vocabulary, std::string record_dir);
  ~MapperService();

  void Start();
  // Maps what is queued, writes the records, stops the worker.
  void Stop();

  int64_t keyframes_received() const { return received_.load(); }
  int64_t keyframes_mapped() const { return mapped_.load(); }
  int64_t submap_resends() const { return resends_.load(); }
  // Keyframes whose fusion and adjustment were cut short or left to the next one (it was waiting).
  int64_t keyframes_hurried() const { return keyframes_hurried_.load(); }
  // Closed submaps let go of (the merger holds them whole, the tracker has dropped them).
  int submaps_released() const { return released_count_.load(); }

 private:
  // What submap updates were published for (their bytes are counted by kind: the stop's log line
  // says where the link's bytes went).
  enum class Sent { kKeyframeUpdate, kFinalState, kManifest, kResend, kCount };
  struct SentBytes {
    int64_t messages = 0, bytes = 0, keyframes = 0, keyframe_bytes = 0;
  };
  void Work();
  void Process(const stitch::keyframe_t& message);
  // Leaves out of a keyframe's submap update the refined points the merger already has close
  // enough (MapperOptions::submap_point_resend_fraction) and associations it already has.
  void ThinForTheLink(SubmapUpdate* update);
  void PublishSubmapUpdate(const SubmapUpdate& update, Sent why);
  void PublishParts(const SubmapUpdate& update, Sent why);  // counted in sent_bytes_
  void CloseIfRequested();
  // Keyframes queued that the mapper does not hold yet (worker only).
  int NewKeyframesWaiting() const;
  // Answers the merger's requests for what the link lost (in the worker: it owns the maps).
  void ResendIfRequested();
  void WriteRecords() const;
  // Lets go of closed submaps the merger holds whole and the tracker has dropped (it sends no
  // more of them): memory stays bounded over a long flight. Their keyframe poses are kept for
  // keyframes.tsv and, with a record folder, their points go to disk for submaps.ply.
  void ReleaseHeldWhole();

  bus::Publisher* publisher_;
  MapperOptions options_;
  OrbOptions orb_;
  ScalePyramid pyramid_;
  const Vocabulary* vocabulary_;
  std::string record_dir_;
  bus::Subscriber subscriber_;
  BoundedQueue<std::unique_ptr<stitch::keyframe_t>> queue_;
  std::unique_ptr<Heartbeat> heartbeat_;
  std::unique_ptr<LocalMapping> mapping_;  // created from the first keyframe's camera
  std::thread worker_;
  std::atomic<bool> running_{false};
  std::atomic<int64_t> received_{0}, mapped_{0}, rejected_{0};
  std::mutex tracker_mutex_;  // what the tracker's statuses say about closed submaps
  int64_t tracker_session_ = 0;
  int64_t keyframe_session_ = 0;  // the sender of the newest keyframe: the tracker
  int tracker_submaps_closed_ = 0;
  int tracker_first_held_ = 0;  // the tracker holds no submap numbered below this
  int64_t close_requested_ = -1;
  std::unordered_map<MapPointId, Eigen::Vector3d> sent_positions_;  // what the merger was last sent
  std::unordered_map<KeyframeId, size_t> sent_associations_;        // (a hash of each keyframe's)
  std::mutex requests_mutex_;
  struct Request {
    std::set<KeyframeId> keyframes;
    bool full_state = false;
  };
  std::map<SubmapId, Request> requests_;   // from the merger
  std::set<SubmapId> confirmed_complete_;  // closed submaps the merger said it holds whole
  // When each keyframe and each submap's whole state may be sent again (MonotonicSeconds();
  // worker only): not while what was last sent is still behind the link bridge's backlog, or the
  // merger's repeated requests would each queue it again (ResendHoldSeconds).
  std::map<KeyframeId, double> keyframe_resend_after_;
  std::map<SubmapId, double> state_resend_after_;
  double ResendHoldSeconds() const;
  void HoldResends(const SubmapUpdate& update, bool whole_state);
  std::atomic<int64_t> resends_{0};
  std::atomic<double> last_request_at_{-1e9};  // MonotonicSeconds() of the merger's last request
  std::atomic<bool> merger_confirms_{false};   // a merger has said it holds a closed submap whole
  // On stop, after closing `last`: answers the merger's requests until it says it holds `last`
  // and every submap closed before it whole (at most stop_linger_s once the link bridge has
  // caught up, stop_link_drain_s at most before that), or, from a merger that never says so,
  // until it stays quiet.
  void LingerForTheMerger(SubmapId last);
  void LogSentBytes() const;
  double last_activity_ = 0;  // MonotonicSeconds() of the last keyframe or manifest sent (worker only)
  int64_t points_thinned_ = 0;
  // The aircraft's link bridge's backlog (from <agent>/LINK_STATUS) and when it last said so.
  double LinkBacklogSeconds() const;  // 0 while the bridge does not report
  bool LinkCongested() const;
  // More than link_backlog_defer_s behind: new keyframes and answers wait (worker only).
  bool LinkDeferring();  // logs when it changes
  bool link_deferring_ = false;
  int64_t keyframes_deferred_ = 0;
  static constexpr size_t kKeyframesPerAnswer = 4;  // ~180 kB: under 2 s of a 100 kB/s link
  std::atomic<double> link_backlog_s_{0}, link_status_at_{-1e9}, link_budget_{0};
  std::atomic<int64_t> bytes_since_link_status_{0};  // published since the bridge's last report
  bool link_congested_ = false;
  int64_t points_held_back_ = 0;
  std::array<SentBytes, static_cast<size_t>(Sent::kCount)> sent_bytes_{};
  std::atomic<int64_t> keyframes_hurried_{0};
  // Submaps let go (ReleaseHeldWhole), their keyframes' final poses, and their points on disk.
  std::set<SubmapId> released_;
  std::atomic<int> released_count_{0};
  std::vector<KeyframeRecord> released_keyframes_;
  std::string released_points_path() const;
};

}  // namespace stitch
