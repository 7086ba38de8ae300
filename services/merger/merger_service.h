#pragma once
// The merger service (ground station): receives submap updates on <agent>/SUBMAP, runs Merger in
// its own worker thread, and publishes the global map on <agent>/GLOBAL_MAP whenever the submap
// graph changes. With a record folder it writes, as the graph changes and at the end:
// submaps.tsv (each submap's merged map and Sim3), graph.dot and graph.png (the submap graph,
// spanning tree in bold), merge_log.tsv (the stack of unconnected submaps and the current map at
// each event, as the method's merging-process table) and retrieval.tsv (each connected-frame
// query's N0, N1, S0, S1, k, l and candidates). Those files are written again at every refinement
// (each whole or not at all), so a merger killed mid-flight leaves its last good map on disk.
// It also takes the aircraft's thin pose stream (<agent>/POSE) and writes the per-frame trajectory
// of the largest merged map, with the images' timestamps, as trajectory.tum (one aircraft) or
// trajectory-<agent>.tum (several) during the flight.

#include <atomic>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "services/common/bus.h"
#include "services/common/service.h"
#include "services/common/update_journal.h"
#include "stitch/frame_pose_t.hpp"
#include "stitch/merging/frame_trajectory.h"
#include "stitch/merging/merger.h"
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

  // Feeds the submap updates recorded in an LCM log (a journal or an lcm-logger recording) through
  // the merger, as if they had arrived; call before Start(). Returns what the reading found (how
  // many, and the damage stepped over).
  SubmapUpdateLogRead Replay(const std::string& log_path);
  void Start();
  // Merges what is queued, writes the records, stops the worker.
  void Stop();

  int64_t updates_received() const { return received_.load(); }
  int64_t updates_processed() const { return processed_.load(); }
  int64_t requests_sent() const { return requests_.load(); }
  int64_t poses_received() const { return poses_received_.load(); }
  // The store; read it only after Stop() (the worker owns it while running).
  const Merger& merger() const { return merger_; }
  // Keyframes listed by manifests but not received, over every submap (as of the last update).
  int64_t keyframes_missing() const { return keyframes_missing_.load(); }
  double last_receive_time() const { return last_receive_.load(); }  // MonotonicSeconds()

 private:
  void Work();
  void Process(const stitch::submap_update_t& message, bool from_journal = false);
  // Refuses (and counts) an update whose revision is negative or jumps far past its aircraft's
  // newest: a forged 2^31-1 would make every later real update of the submap look stale. Live
  // updates only (a journal or a recording holds no timing to judge by).
  bool PlausibleRevision(const stitch::submap_update_t& message);
  // Asks the mapper for keyframes a manifest lists but never arrived, and for the final state of
  // a submap left open while a newer one of its aircraft goes on (its closing update was lost).
  void RequestWhatWasLost();
  void OnGraphChange(const std::string& event);
  void PublishGlobalMap(const Merger::Graph& graph);
  // The largest merged map with its points fused and bundle adjusted; its keyframe poses replace
  // the pose graph's in `graph`. nullopt when it holds one submap.
  std::optional<MergedMap> MergeLargestMap(Merger::Graph* graph) const;
  // Pose graph, merged map and bundle adjustment, then publishes; kept in refined_.
  void Refine(const std::string& why);
  void WriteRecords(const Merger::Graph& graph, const MergedMap* merged) const;
  // Takes a pose of the stream after its checks (subscriber thread); false: refused, with why.
  bool TakePose(const stitch::frame_pose_t& message, std::string* why);
  // trajectory.tum (or one per aircraft): every frame of the pose stream that lies in the largest
  // merged map, placed with the newest placement and the last refinement's keyframe poses.
  void WriteLiveTrajectory();
  // <station>/MAP_CLOUD: every placed submap's points in its merged map's frame (the refined
  // merged map's where it still holds), thinned to map_cloud_points.
  void PublishMapCloud();
  // colmap/ in the record folder: the largest map as a COLMAP sparse model (docs/tools.md), at
  // the end only (the other records are written at every refinement too).
  void WriteColmapRecord(const Merger::Graph& graph, const MergedMap* merged) const;

  bus::Publisher* publisher_;
  ScalePyramid pyramid_;
  std::string record_dir_;
  Merger merger_;
  bus::Subscriber subscriber_;
  BoundedQueue<std::unique_ptr<stitch::submap_update_t>> queue_;
  std::unique_ptr<Heartbeat> heartbeat_;
  std::unique_ptr<UpdateJournal> journal_;
  bool journal_failed_ = false;
  bool recovering_ = false;
  std::thread worker_;
  std::atomic<bool> running_{false};
  std::atomic<int64_t> received_{0}, processed_{0}, rejected_{0};
  std::atomic<double> last_receive_{0};
  size_t connections_seen_ = 0;
  std::map<SubmapId, bool> closed_seen_;
  std::set<SubmapId> refined_closed_;                      // closed submaps the merged maps were refined with
  std::map<SubmapId, double> last_request_, last_update_;  // MonotonicSeconds()
  std::map<KeyframeId, double> missing_since_;             // listed by a manifest, not received
  struct FinalStateParts {
    int64_t revision = -1;
    int32_t num_parts = 0;
    std::set<int32_t> received;
  };
  std::map<SubmapId, FinalStateParts> final_parts_;  // each closed submap's newest final state, as it arrives
  std::set<SubmapId> final_whole_;                   // closed submaps whose final state arrived in all its parts
  std::set<SubmapId> confirmed_complete_;            // of those, the ones the mapper was told are held whole
  std::vector<std::string> agents_;                  // whose submaps it merges
  std::set<std::string> submap_channels_;            // their <agent>/SUBMAP
  std::map<SubmapId, std::string> agent_of_;         // each submap's aircraft (from its updates)
  struct NewestRevision {
    int64_t revision = 0;
    double heard_at = 0;  // MonotonicSeconds()
  };
  std::map<std::string, NewestRevision> newest_revision_;  // per aircraft, live updates only
  std::atomic<int64_t> requests_{0}, keyframes_missing_{0};
  std::vector<MergeLogRecord> merge_log_;  // merge_log.tsv
  std::string last_stack_;
  std::map<std::pair<SubmapId, SubmapId>, std::string> refused_edges_;  // as last logged
  int revision_ = 0;
  std::map<SubmapId, SubmapPlacement> latest_placement_;  // as last published
  // The pose stream: what the subscriber took, waiting for the worker, and the worker's copy by
  // aircraft and frame.
  std::mutex poses_mutex_;
  std::vector<std::pair<std::string, TrackedFramePose>> poses_pending_;
  std::map<std::string, std::map<int, TrackedFramePose>> frame_poses_;
  std::atomic<int64_t> poses_received_{0};
  bool trajectory_stale_ = false;
  bool cloud_stale_ = false;
  double cloud_published_at_ = -1e9;  // MonotonicSeconds()
  int cloud_revision_ = 0;
  double trajectory_written_at_ = 0;  // MonotonicSeconds()
  struct Refined {
    Merger::Graph graph;
    std::optional<MergedMap> merged;
  };
  std::optional<Refined> refined_;  // the latest refinement...
  int64_t refined_at_ = -1;         // ...after this many processed updates
};

}  // namespace stitch
