#pragma once
// The mapper's per-keyframe algorithm (no LCM here; MapperService carries it over the bus), as
// ORB-SLAM2's local mapping, one stage after another (each its own unit):
//   1. insert the keyframe and update the covisibility graph;
//   2. cull recently created points that are rarely found (RecentPoints, culling.h);
//   3. triangulate new points with the best covisible keyframes (new_points.h);
//   4. fuse duplicates with the neighbourhood (new_points.h);
//   5. local bundle adjustment (estimators/bundle_adjustment.h);
//   6. cull redundant keyframes (culling.h).
// When the next keyframe is already waiting (as ORB-SLAM's local mapping does), stages 4-6 are
// left to the next keyframe and a running bundle adjustment stops at its next iteration: the
// mapper keeps up with the tracker rather than polishing a window the next keyframe reopens.
// The new points can go to the tracker as soon as they are made (MappingHooks), before the
// slower stages: a tracker that does not wait for the mapper tracks them a few frames sooner.
// It holds the authoritative copy of the current submap (and the closed ones), and makes what
// the tracker and the merger are told after each keyframe (MapKeyframe). One owner thread.

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "stitch/estimators/bundle_adjustment.h"
#include "stitch/features/vocabulary.h"
#include "stitch/map/local_map_update.h"
#include "stitch/map/map.h"
#include "stitch/map/submap_update.h"
#include "stitch/map/view_geometry.h"
#include "stitch/mapping/culling.h"
#include "stitch/mapping/mapping_options.h"

namespace stitch {

// Milliseconds spent in each stage of one keyframe (0 for a stage that did not run).
struct MappingStageTimes {
  double insert = 0, cull_points = 0, triangulate = 0, fuse = 0, bundle_adjustment = 0, cull_keyframes = 0;
};

struct MappingReport {
  KeyframeId keyframe;
  bool duplicate = false;                   // the mapper had this keyframe already: nothing was done
  std::optional<SubmapId> closed_submap;    // the keyframe began a new submap and closed this one
  std::optional<SubmapId> reopened_submap;  // the keyframe belongs to this closed submap, current again
  int new_points = 0;
  int fused = 0;
  int culled_points = 0;
  std::vector<KeyframeId> culled_keyframes;
  BundleAdjustmentReport bundle_adjustment;
  bool deferred = false;  // the next keyframe was waiting: fusion, adjustment and culling left to it
  double milliseconds = 0;
  MappingStageTimes stage_ms;
};

// What one keyframe gives the mapper's receivers, in the order they are to be sent.
struct MappedKeyframe {
  MappingReport report;
  std::optional<SubmapUpdate> closed_final;  // the final state of the submap the keyframe closed
  LocalMapUpdate for_tracker;                // the window's changes (queued_keyframes left to the caller)
  SubmapUpdate for_merger;                   // the keyframe in full and the same changes (empty for a duplicate)
};

// What the caller of MapKeyframe may give (each optional).
struct MappingHooks {
  Interruption next_waiting;  // whether another keyframe waits to be mapped
  // The new points and their associations (MakeNewPointsUpdate), as soon as they are made.
  std::function<void(const LocalMapUpdate&)> new_points_made;
};

class LocalMapping {
 public:
  // `vocabulary` must outlive the mapper.
  LocalMapping(const MappingOptions& options, const Camera& camera, const OrbOptions& orb,
               const Vocabulary* vocabulary);

  // The per-keyframe protocol, the same over the bus and inline: processes the keyframe
  // (ProcessKeyframe), then makes the closed submap's final state, the tracker's update and the
  // merger's update, in the order they are to be sent.
  MappedKeyframe MapKeyframe(Keyframe keyframe, const std::vector<MapPoint>& new_points,
                             const MappingHooks& hooks = {});

  // Processes one keyframe from the tracker, with the points it created (the initial map).
  // A keyframe of another submap than the current one closes the current submap first; one of
  // a closed submap reopens that submap.
  MappingReport ProcessKeyframe(Keyframe keyframe, const std::vector<MapPoint>& new_points,
                                const MappingHooks& hooks = {});
  // What the tracker needs to know after the last keyframe.
  LocalMapUpdate MakeUpdate(KeyframeId keyframe, int queued_keyframes);
  // What the merger needs to know after the last keyframe: the keyframe in full and `changes`
  // (the update just made for the tracker).
  SubmapUpdate MakeSubmapUpdate(KeyframeId keyframe, const LocalMapUpdate& changes) const;
  // The final state of a closed submap (empty update for one it does not know).
  SubmapUpdate MakeFinalSubmapUpdate(SubmapId submap);
  // Part of a submap again, open or closed, for a receiver that lost it: those of `keyframes` it
  // still holds, in full with the points they observe, and with `full_state` every pose,
  // association and point (closed as it is). A closed submap's keyframes without its state go
  // alone (no points: the final state has them) as revision 0, no news of the submap's state.
  // Empty for a submap it does not know.
  SubmapUpdate MakeResendUpdate(SubmapId submap, const std::vector<KeyframeId>& keyframes, bool full_state);
  // Whether the current or a closed submap holds this keyframe (not culled, not let go), or is
  // this submap.
  bool Holds(KeyframeId keyframe) const;
  bool Holds(SubmapId submap) const;
  // The current submap's manifest alone (a few bytes per keyframe): lets a receiver that lost
  // the newest keyframe's update notice it while the aircraft makes no new keyframe.
  SubmapUpdate MakeManifestUpdate();

  const Map* map() const { return map_.get(); }
  // Submaps closed so far (the current one is not among them).
  const std::vector<std::unique_ptr<Map>>& closed_maps() const { return closed_maps_; }
  std::optional<SubmapId> CloseSubmap();
  // Lets a closed submap go (the merger holds it whole and the tracker will send no more of it):
  // its map, and its culled keyframes with their final poses. Null map for one not closed here.
  struct Released {
    std::unique_ptr<Map> map;
    std::vector<CulledKeyframe> culled;
  };
  Released ReleaseClosed(SubmapId submap);
  // Culled keyframes with their poses as the map places them now (observations left out): each
  // against the refined points it observed (`repose_culled_keyframes`), else, or where too few
  // of them agree, through its parents at the relative poses it had when culled. Those of
  // `submap` alone where it is valid.
  std::vector<CulledKeyframe> CulledKeyframePoses(SubmapId submap = SubmapId()) const;

 private:
  Map* FindSubmap(SubmapId submap) const;  // the current or a closed one; null if neither
  void InsertKeyframe(Keyframe keyframe, const std::vector<MapPoint>& new_points);

  MappingOptions options_;
  ViewGeometry geometry_;
  const Vocabulary* vocabulary_;
  std::unique_ptr<Map> map_;
  std::vector<std::unique_ptr<Map>> closed_maps_;
  RecentPoints recent_points_;
  std::vector<CulledKeyframe> culled_;
  int keyframes_processed_ = 0;
  int revision_ = 0;
  KeyframeId first_keyframe_;
};

}  // namespace stitch
