#pragma once
// The mapper service: the bus around LocalMapping and a SubmapSender. It receives keyframes on
// <agent>/KEYFRAME, maps each in its own worker thread, publishes what changed on
// <agent>/LOCAL_MAP for the tracker, and delivers the submaps to the merger on <agent>/SUBMAP
// (in parts of about 60 kB; src/stitch/delivery/submap_sender.h): a closed submap's final state
// goes out when the tracker reports the submap closed (<agent>/TRACKING_STATUS), else when the
// next submap's first keyframe arrives, or at Stop. A keyframe of a closed submap reopens it. It
// answers the merger's requests (<agent>/SUBMAP_REQUEST), follows the link bridge's backlog
// (<agent>/LINK_STATUS), and lets go of closed submaps the merger holds whole once the tracker
// has dropped them. When given a record folder it writes, at the end, submaps.ply (every
// submap's points in its own frame, one colour per submap) and keyframes.tsv (final keyframe
// poses, culled keyframes included).

#include <atomic>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "services/common/bus.h"
#include "services/common/service.h"
#include "stitch/config/mapper_options.h"
#include "stitch/delivery/submap_sender.h"
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
  // Maps what is queued, delivers the last submap, writes the records, stops the worker.
  void Stop();

  int64_t keyframes_received() const { return received_.load(); }
  int64_t keyframes_mapped() const { return mapped_.load(); }
  int64_t submap_resends() const { return sender_.resends(); }
  // Keyframes whose fusion and adjustment were cut short or left to the next one (it was waiting).
  int64_t keyframes_hurried() const { return keyframes_hurried_.load(); }
  // Closed submaps let go of (the merger holds them whole, the tracker has dropped them).
  int submaps_released() const { return released_count_.load(); }

 private:
  // The sender's view of the mapper's submaps (none before the first keyframe).
  class MappingSource : public SubmapSource {
   public:
    explicit MappingSource(const std::unique_ptr<LocalMapping>* mapping) : mapping_(mapping) {}
    const Map* current() const override;
    std::vector<SubmapId> closed() const override;
    bool Holds(SubmapId submap) const override;
    bool Holds(KeyframeId keyframe) const override;
    SubmapUpdate MakeResendUpdate(SubmapId submap, const std::vector<KeyframeId>& keyframes, bool full_state) override;
    SubmapUpdate MakeManifestUpdate() override;

   private:
    const std::unique_ptr<LocalMapping>* mapping_;
  };

  void Work();
  void Process(const stitch::keyframe_t& message);
  void CloseIfRequested();
  // Keyframes queued that the mapper does not hold yet (worker only).
  int NewKeyframesWaiting() const;
  void PublishLocalMap(const LocalMapUpdate& update);
  void WriteRecords() const;
  // Lets go of closed submaps the merger holds whole and the tracker has dropped (it sends no
  // more of them): memory stays bounded over a long flight. Their keyframe poses are kept for
  // keyframes.tsv and, with a record folder, their points go to disk for submaps.ply.
  void ReleaseHeldWhole();
  std::string released_points_path() const;

  bus::Publisher* publisher_;
  MapperOptions options_;
  OrbOptions orb_;
  ScalePyramid pyramid_;
  const Vocabulary* vocabulary_;
  std::string record_dir_;
  std::unique_ptr<LocalMapping> mapping_;  // created from the first keyframe's camera
  MappingSource source_{&mapping_};
  SubmapSender sender_;
  bus::Subscriber subscriber_;
  BoundedQueue<std::unique_ptr<stitch::keyframe_t>> queue_;
  std::unique_ptr<Heartbeat> heartbeat_;
  std::thread worker_;
  std::atomic<bool> running_{false};
  std::atomic<int64_t> received_{0}, mapped_{0}, rejected_{0};
  std::mutex tracker_mutex_;  // what the tracker's statuses say about closed submaps
  int64_t tracker_session_ = 0;
  int64_t keyframe_session_ = 0;  // the sender of the newest keyframe: the tracker
  int tracker_submaps_closed_ = 0;
  int tracker_first_held_ = 0;  // the tracker holds no submap numbered below this
  int64_t close_requested_ = -1;
  std::atomic<int64_t> keyframes_hurried_{0};
  // Submaps let go (ReleaseHeldWhole), their keyframes' final poses, and their points on disk.
  std::set<SubmapId> released_;
  std::atomic<int> released_count_{0};
  std::vector<KeyframeRecord> released_keyframes_;
};

}  // namespace stitch
