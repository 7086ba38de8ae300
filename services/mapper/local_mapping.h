#pragma once
// The mapper's per-keyframe algorithm (no LCM here; MapperService carries it over the bus), as
// ORB-SLAM2's local mapping: insert the keyframe and update the covisibility graph, cull
// recently created points that are rarely found, triangulate new points with the best covisible
// keyframes, fuse duplicates with the neighbourhood, run local bundle adjustment, and cull
// redundant keyframes. Holds the authoritative copy of the current submap. One owner thread.

#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "stitch/estimators/bundle_adjustment.h"
#include "stitch/features/vocabulary.h"
#include "stitch/map/local_map_update.h"
#include "stitch/map/map.h"
#include "stitch/map/submap_update.h"

namespace stitch {

struct MappingOptions {
  int triangulation_neighbours = 20;     // covisible keyframes to triangulate with
  double min_baseline_ratio = 0.01;      // baseline / median depth to try a neighbour
  int fuse_neighbours = 20;              // first-order neighbours searched for duplicates
  double point_min_found_ratio = 0.25;   // recent points found in fewer of the frames predicting them are culled
  int point_min_observations = 2;        // recent points with this few observations after 2 keyframes are culled
  double keyframe_redundancy = 0.9;      // keyframes whose points are this much seen by 3 others are culled
  bool cull_keyframes = true;
  BundleAdjustmentOptions local_bundle_adjustment;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("triangulation_neighbours", triangulation_neighbours, "covisible keyframes to triangulate new points with");
    v("min_baseline_ratio", min_baseline_ratio, "baseline / median depth below which a neighbour is not used");
    v("fuse_neighbours", fuse_neighbours, "neighbour keyframes searched for duplicate points");
    v("point_min_found_ratio", point_min_found_ratio, "new points found in fewer of the keyframes predicting them are culled");
    v("point_min_observations", point_min_observations, "new points observed this few times after two keyframes are culled");
    v("keyframe_redundancy", keyframe_redundancy, "keyframes whose points this fraction is seen by 3 others are culled");
    v("cull_keyframes", cull_keyframes, "remove redundant keyframes");
    v("local_bundle_adjustment", local_bundle_adjustment, "local bundle adjustment");
  }
  bool Check(std::string* why) const;
};

// A keyframe removed as redundant; its final pose follows its parent in the spanning tree.
struct CulledKeyframe {
  KeyframeId id;
  int frame_index = -1;
  int64_t t_ns = 0;
  Rigid3d cam_from_world;  // resolved by CulledKeyframePoses()
};

struct MappingReport {
  KeyframeId keyframe;
  std::optional<SubmapId> closed_submap;    // the keyframe began a new submap and closed this one
  std::optional<SubmapId> reopened_submap;  // the keyframe belongs to this closed submap, current again
  int new_points = 0;
  int fused = 0;
  int culled_points = 0;
  std::vector<KeyframeId> culled_keyframes;
  BundleAdjustmentReport bundle_adjustment;
  double milliseconds = 0;
};

class LocalMapping {
 public:
  // `vocabulary` must outlive the mapper.
  LocalMapping(const MappingOptions& options, const Camera& camera, const OrbOptions& orb, const Vocabulary* vocabulary);

  // Processes one keyframe from the tracker, with the points it created (the initial map).
  // A keyframe of another submap than the current one closes the current submap first; one of
  // a closed submap reopens that submap.
  MappingReport ProcessKeyframe(Keyframe keyframe, const std::vector<MapPoint>& new_points);
  // What the tracker needs to know after the last keyframe.
  LocalMapUpdate MakeUpdate(KeyframeId keyframe, int queued_keyframes);
  // What the merger needs to know after the last keyframe: the keyframe in full and `changes`
  // (the update just made for the tracker).
  SubmapUpdate MakeSubmapUpdate(KeyframeId keyframe, const LocalMapUpdate& changes) const;
  // The final state of a closed submap (empty update for one it does not know).
  SubmapUpdate MakeFinalSubmapUpdate(SubmapId submap);
  // Part of a submap again, open or closed, for a receiver that lost it: those of `keyframes` it
  // still holds, in full with the points they observe, and with `full_state` (always, for a
  // closed submap) every pose, association and point. Empty for a submap it does not know.
  SubmapUpdate MakeResendUpdate(SubmapId submap, const std::vector<KeyframeId>& keyframes, bool full_state);
  // The current submap's manifest alone (a few bytes per keyframe): lets a receiver that lost
  // the newest keyframe's update notice it while the aircraft makes no new keyframe.
  SubmapUpdate MakeManifestUpdate();

  const Map* map() const { return map_.get(); }
  // Submaps closed so far (the current one is not among them).
  const std::vector<std::unique_ptr<Map>>& closed_maps() const { return closed_maps_; }
  std::optional<SubmapId> CloseSubmap();
  // Culled keyframes with their poses as the final map places them (through their parents).
  std::vector<CulledKeyframe> CulledKeyframePoses() const;

 private:
  void InsertKeyframe(Keyframe keyframe, const std::vector<MapPoint>& new_points);
  int CullRecentPoints(KeyframeId keyframe);
  int TriangulateNewPoints(KeyframeId keyframe);
  int FuseWithNeighbours(KeyframeId keyframe);
  std::vector<KeyframeId> CullKeyframes(KeyframeId keyframe);

  MappingOptions options_;
  Camera camera_;
  PinholeIntrinsics intrinsics_;
  ScalePyramid pyramid_;
  Undistorter undistorter_;
  const Vocabulary* vocabulary_;
  std::unique_ptr<Map> map_;
  std::vector<std::unique_ptr<Map>> closed_maps_;
  struct RecentPoint {
    MapPointId id;
    int created_at;  // keyframe count when created
  };
  std::deque<RecentPoint> recent_points_;
  struct CulledRecord {
    CulledKeyframe keyframe;
    KeyframeId parent;          // invalid: `cam_from_parent` is cam_from_world
    Rigid3d cam_from_parent;
  };
  std::vector<CulledRecord> culled_;
  int keyframes_processed_ = 0;
  int revision_ = 0;
  KeyframeId first_keyframe_;
};

}  // namespace stitch
