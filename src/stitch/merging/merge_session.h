#pragma once
// One merging session on the ground (no LCM here): the merger's store and submap graph (Merger),
// the refinement of the merged maps (connected frames verified again, pose graph, fused points and
// bundle adjustment) with the check after placement and its rollback, the merge log (the method's
// merging-process table), the per-frame trajectory of the largest merged map from the aircraft's
// pose stream, the map cloud, and the merger's record folder. The merger service carries it over
// the bus (subscribe, queue, journal, publish), `stitch map` replays a journal through it, and the
// inline pipeline feeds it directly. One owner thread, but for AddFramePose.

#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "stitch/geo/gnss_fix.h"
#include "stitch/mosaic/live_mosaic.h"
#include "stitch/records/keyframe_pictures.h"

#include "stitch/merging/frame_trajectory.h"
#include "stitch/merging/merger.h"
#include "stitch/records/merger_records.h"

namespace stitch {

class MergeSession {
 public:
  // `vocabulary` must outlive the session. With a `record_dir` the records (submaps.tsv, map.ply,
  // edges.tsv, ... docs/merger.md) are written there at every refinement and at Finish, and the
  // live trajectory as trajectory.tum (one aircraft in `agents`) or trajectory-<agent>.tum.
  MergeSession(const MergerOptions& options, const Vocabulary* vocabulary, const ScalePyramid& pyramid,
               std::string record_dir = "", std::vector<std::string> agents = {});

  // Called with every graph worth showing (a change of the merged maps, a refinement); the
  // service publishes it as <agent>/GLOBAL_MAP.
  void OnGraph(std::function<void(const Merger::Graph&)> listener) { on_graph_ = std::move(listener); }

  struct Applied {
    bool accepted = false;
    std::string refused;              // why it was not (another aircraft's submap)
    std::vector<KeyframeId> missing;  // keyframes the submap's manifest lists and its copy lacks
    bool newly_closed = false;        // the update closed its submap
  };
  // Applies one update (or part of one, `first_part` for part 0) from `agent`'s mapper.
  Applied Apply(const SubmapUpdate& update, const std::string& agent, bool first_part);

  // Whether `submap`'s final state, arrived whole, is the first of that submap to: a closed
  // submap changes the merged maps for good, and the host refines them then.
  bool FirstWholeFinalState(SubmapId submap) { return refined_closed_.insert(submap).second; }
  bool any_closed_whole() const { return !refined_closed_.empty(); }

  // Verifies stale connected frames again, solves the graph with the pose graph, assembles the
  // largest merged map and adjusts it; a merge whose junction the adjustment cannot hold is
  // rolled back (its edge refused) and the maps solved again, up to 3 rounds. Then shows the
  // graph and writes the records and the live trajectory.
  void Refine(const std::string& why);
  // At the end: refines if updates arrived since the last refinement (else writes the records of
  // that one), says which submaps are incomplete, and writes the COLMAP model and the trajectory.
  // Returns whether it refined.
  bool Finish();

  // The latest refinement.
  struct Refined {
    Merger::Graph graph;
    std::optional<MergedMap> merged;  // the largest merged map, fused and adjusted
  };
  const std::optional<Refined>& refined() const { return refined_; }
  // The placement of the graph shown last.
  const std::map<SubmapId, SubmapPlacement>& latest_placement() const { return latest_placement_; }

  // The pose stream. Refuses (false, with why) a pose that names no submap, or frames beyond
  // 9 hours at 30 fps waiting; thread-safe (the subscriber's thread calls it).
  bool AddFramePose(const std::string& agent, const TrackedFramePose& pose, std::string* why);
  int64_t frame_poses_received() const;
  // The aircraft's GNSS fixes (<agent>/GNSS): kept by aircraft and time (a fix again at a time
  // already held replaces it), written to gnss_received.csv (gnss_received-<agent>.csv for
  // several aircraft) with the records. Refuses (false, with why) a fix that is no place on Earth
  // or states no accuracy, and fixes beyond 10 hours at 10 Hz; thread-safe.
  bool AddGnssFix(const std::string& agent, const GnssFix& fix, std::string* why);
  // The origin of the ENU frame the fixes join and place the maps in (Merger::Graph::on_earth):
  // the first usable fix received; nullopt before it. Thread-safe.
  std::optional<GeodeticPoint> gnss_origin() const;
  // A keyframe's picture the aircraft sent (merger.mosaic.live): laid on the live mosaic at its
  // next update. Refuses (false, with why) pictures beyond 10,000 waiting; thread-safe.
  bool AddKeyframePicture(const KeyframePicture& picture, std::string* why);
  // merger.mosaic.live, every merger.live_outputs_interval_s: the pictures received laid where
  // the largest merged map places their frames now, and where it is on Earth every map the fixes
  // place, each where they put it (live_mosaic.h), written as mosaic_live.tif
  // with the records (at most a tenth of the merger's time).
  void UpdateMosaicIfDue();
  const LiveMosaic* live_mosaic() const { return live_mosaic_ ? &*live_mosaic_ : nullptr; }
  // merger.mosaic.publish_tiles: the live mosaic's tiles drawn anew since the last call (for the
  // viewer), and the newest sending time of the pictures laid since (their header's utime; 0
  // where none was laid: the tiles only moved or were drawn again).
  struct MosaicTiles {
    std::vector<LiveMosaicTile> tiles;
    int64_t newest_picture_utime = 0;
  };
  MosaicTiles TakeMosaicTiles();

  // trajectory.tum (or one per aircraft): every frame of the pose stream that lies in the
  // largest merged map, with the newest placement and the last refinement's keyframe poses.
  void WriteLiveTrajectory();
  // ...when merger.live_outputs_interval_s has passed since it was last written.
  void WriteLiveTrajectoryIfDue();

  // Every placed submap's points in its merged map's frame (the refined merged map's where it
  // still holds), less those map.ply leaves out (merger.map_export, per merged map), thinned to
  // merger.map_cloud_points in all.
  struct MapCloud {
    int revision = 0;
    int64_t points_in_maps = 0;  // kept, before thinning
    struct Submap {
      SubmapId id;
      int component = -1;
      std::vector<Eigen::Vector3f> positions;
      int keyframes = 0;  // the submap's keyframes the merger held
    };
    std::vector<Submap> submaps;
  };
  // Whether the maps changed since the last cloud (a graph shown, or an update applied).
  bool map_cloud_stale() const { return cloud_stale_; }
  // The cloud (nullopt when none is wanted or nothing is placed); no longer stale after.
  std::optional<MapCloud> TakeMapCloud();

  const Merger& merger() const { return merger_; }
  const std::vector<MergeLogRecord>& merge_log() const { return merge_log_; }
  // Each submap's aircraft (from its updates).
  const std::map<SubmapId, std::string>& agent_of() const { return agent_of_; }
  int64_t updates_applied() const { return applied_; }

  // The records of the graph and map given (what Refine and Finish write).
  void WriteRecords(const Merger::Graph& graph, const MergedMap* merged) const;

 private:
  // Logs a change of the current map and the stack, and refused edges; shows the graph.
  void OnGraphChange(const std::string& event);
  void Show(const Merger::Graph& graph);
  // The largest merged map with its points fused and bundle adjusted; its keyframe poses replace
  // the pose graph's in `graph`. nullopt when it holds no submap with a camera. `fixes` (the
  // submaps' fixes the graph was solved with) hold it in the adjustment where it is on Earth.
  std::optional<MergedMap> MergeLargestMap(Merger::Graph* graph, const SubmapFixes& fixes) const;
  // Each submap's usable fixes over its keyframes' times (and the interpolation gap on each
  // side), in the plane of the first fix; none where merger.join_by_gnss is off.
  SubmapFixes FixesOfSubmaps() const;
  // colmap/: the largest map as a COLMAP sparse model (at the end only).
  void WriteColmapRecord(const Merger::Graph& graph, const MergedMap* merged) const;
  // map.stitchmap: the largest map as a saved map (merger.save_map; at the end only).
  void WriteSavedMap(const Merger::Graph& graph, const MergedMap* merged) const;
  // The largest merged map as one Map: the refined one, else the first of its submaps with a
  // camera; nullptr where none.
  const Map* LargestMap(const Merger::Graph& graph, const MergedMap* merged) const;
  // The camera of a keyframe's submap (nullptr until one of its keyframes arrived).
  const Camera* CameraOf(KeyframeId keyframe) const;
  // merger.prior_map: the saved map as a closed submap of agent "saved map" (kSavedMapAgent), which
  // roots its merged map. Throws stitch::Error for a file it cannot use.
  void LoadPriorMap(const std::string& path);
  std::optional<std::string> prior_map_description_;

  ScalePyramid pyramid_;
  Merger merger_;
  std::string record_dir_;
  std::vector<std::string> agents_;
  std::function<void(const Merger::Graph&)> on_graph_;
  int64_t applied_ = 0;
  size_t connections_seen_ = 0;
  std::map<SubmapId, bool> closed_seen_;
  std::set<SubmapId> refined_closed_;         // closed submaps the merged maps were refined with
  std::map<SubmapId, std::string> agent_of_;  // each submap's aircraft (from its updates)
  std::vector<MergeLogRecord> merge_log_;     // merge_log.tsv
  std::string last_stack_;
  std::map<std::pair<SubmapId, SubmapId>, std::string> refused_edges_;  // as last logged
  std::map<std::pair<SubmapId, SubmapId>, double> gnss_junctions_;      // as last logged, with their sigma
  std::map<SubmapId, std::string> not_joined_by_gnss_;                  // as last logged
  std::map<SubmapId, SubmapPlacement> latest_placement_;                // as last shown
  std::map<int, MergedMapOnEarth> latest_on_earth_;                     // as last shown, by component
  std::optional<Refined> refined_;
  int64_t refined_at_ = -1;  // ...after this many updates applied
  // The pose stream: what the subscriber took, waiting, and the owner's copy by aircraft and frame.
  mutable std::mutex poses_mutex_;
  std::vector<std::pair<std::string, TrackedFramePose>> poses_pending_;
  std::vector<KeyframePicture> pictures_pending_;  // under poses_mutex_
  // Moves the pose stream's pending frames into frame_poses_ (the worker's).
  void TakePendingPoses();
  // The maps the live mosaic lays pictures on: the largest merged map; where the fixes place it on
  // Earth, every map they place, in their ENU frame.
  LiveMosaic::MapState MapsForMosaic(const std::map<int, std::pair<std::string, int>>& pictured) const;
  std::optional<LiveMosaic> live_mosaic_;
  std::map<int, std::pair<std::string, int>> pictured_;  // live mosaic key -> (agent, frame)
  double mosaic_updated_at_ = 0, mosaic_written_at_ = 0, mosaic_write_cost_s_ = 0;
  bool mosaic_unwritten_ = false;
  MosaicTiles mosaic_tiles_;          // made, not taken yet
  int64_t newest_picture_utime_ = 0;  // of the pictures taken since pictures were last laid
  bool mosaic_failed_ = false;        // said once; the flight goes on without it
  std::string mosaic_waits_for_;      // what the live mosaic waited for when last said
  struct MosaicCost {
    int updates = 0, laid = 0, moved = 0, redrawn = 0, writes = 0;
    double update_ms = 0, write_ms = 0;
  } mosaic_cost_;
  void UpdateMosaic();
  void WriteLiveMosaic();
  int64_t poses_received_ = 0;
  std::map<std::string, std::map<int, TrackedFramePose>> frame_poses_;
  bool trajectory_stale_ = false;
  mutable std::mutex gnss_mutex_;
  struct HeldFix {
    GnssFix fix;
    std::optional<EnuFix> enu;  // a usable fix in gnss_plane_, for joining maps
  };
  std::map<std::string, std::map<int64_t, HeldFix>> gnss_;  // by aircraft, by time
  std::optional<LocalTangentPlane> gnss_plane_;             // at the first usable fix received
  double trajectory_written_at_ = 0;                        // MonotonicSeconds()
  bool cloud_stale_ = false;
  int cloud_revision_ = 0;
};

}  // namespace stitch
