#pragma once
// The merger service (ground station): the bus around a MergeSession and a SubmapReceiver. It
// receives submap updates on <agent>/SUBMAP (each aircraft's), journals them (with a state
// folder), applies them in its own worker thread, asks the mappers on <agent>/SUBMAP_REQUEST for
// what the link lost, and publishes the merged maps on <agent>/GLOBAL_MAP and their points on
// <agent>/MAP_CLOUD. The aircraft's pose stream (<agent>/POSE) feeds the session's per-frame
// trajectory; its GNSS fixes (<agent>/GNSS) are kept and written with the records. With a record folder the session
// writes the merger's records there (src/stitch/merging/merge_session.h).

#include <atomic>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "services/common/bus.h"
#include "services/common/service.h"
#include "services/common/update_journal.h"
#include "stitch/delivery/submap_receiver.h"
#include "stitch/frame_pose_t.hpp"
#include "stitch/gnss_fix_t.hpp"
#include "stitch/merging/merge_session.h"
#include "stitch/records/keyframe_pictures.h"
#include "stitch/submap_update_t.hpp"
#include "stitch/util/bounded_queue.h"

namespace stitch {

class MergerService {
 public:
  // Subscribes at once: construct before the Dispatcher starts. `vocabulary` must outlive it.
  // With a `state_dir`, every accepted update is journaled there (UpdateJournal) and Start()
  // first resumes from what the folder already holds.
  // `agents`: the aircraft whose <agent>/SUBMAP it merges (empty: the publisher's own agent).
  MergerService(lcm::LCM* lcm, bus::Publisher* publisher, const MergerOptions& options, const OrbOptions& orb,
                const Vocabulary* vocabulary, std::string record_dir, const std::string& state_dir = "",
                std::vector<std::string> agents = {});
  ~MergerService();

  void Start();
  // Merges what is queued, writes the records, stops the worker.
  void Stop();

  int64_t updates_received() const { return received_.load(); }
  int64_t updates_processed() const { return processed_.load(); }
  int64_t requests_sent() const { return requests_.load(); }
  // The store; read it only after Stop() (the worker owns it while running).
  const Merger& merger() const { return session_.merger(); }
  // Keyframes listed by manifests but not received, over every submap (as of the last update).
  int64_t keyframes_missing() const { return keyframes_missing_.load(); }
  double last_receive_time() const { return last_receive_.load(); }  // MonotonicSeconds()

 private:
  void Work();
  void Process(const stitch::submap_update_t& message, bool from_journal = false);
  // The fix `message` holds, kept by the session; false with `why` where it is none or refused.
  bool AddGnssFix(const stitch::gnss_fix_t& message, std::string* why);
  // Appends a submap update or a GNSS fix to the journal (when there is one and it still works).
  template <class Message>
  void Journal(const Message& message);
  // Asks the mappers for what the link lost, and tells them which closed submaps are held whole.
  void RequestWhatWasLost();
  void Refine(const std::string& why);
  void PublishGlobalMap(const Merger::Graph& graph);
  void PublishMapCloud();
  void PublishMosaicTiles();

  bus::Publisher* publisher_;
  ScalePyramid pyramid_;
  std::vector<std::string> agents_;  // whose submaps it merges
  MergeSession session_;
  SubmapReceiver receiver_;
  bus::Subscriber subscriber_;
  BoundedQueue<std::unique_ptr<stitch::submap_update_t>> queue_;
  std::unique_ptr<Heartbeat> heartbeat_;
  std::unique_ptr<UpdateJournal> journal_;
  KeyframePictureStore pictures_;  // the keyframes' pictures received, with the records (dispatcher thread)
  std::atomic<bool> journal_failed_{false};
  bool recovering_ = false;
  std::thread worker_;
  std::atomic<bool> running_{false};
  std::atomic<int64_t> received_{0}, processed_{0}, rejected_{0}, requests_{0}, keyframes_missing_{0};
  std::atomic<double> last_receive_{0};
  int revision_ = 0;                  // of the global map
  double cloud_published_at_ = -1e9;  // MonotonicSeconds()
  double cloud_cost_s_ = 0;           // what the last cloud took to make and publish
};

}  // namespace stitch
