#pragma once
// What the mapper tells the tracker after a keyframe: refined poses, which point each feature
// of the window's keyframes observes, new or refined points, and what it removed. The tracker
// applies it to its own copy of the submap (ApplyLocalMapUpdate). Applying an update twice, or
// updates in parts, leaves the same map.

#include <utility>
#include <vector>

#include "stitch/map/map.h"

namespace stitch {

struct LocalMapUpdate {
  SubmapId submap;
  int revision = 0;
  KeyframeId last_keyframe;  // newest keyframe the mapper has processed
  int queued_keyframes = 0;
  std::vector<std::pair<KeyframeId, Rigid3d>> keyframe_poses;                // cam_from_world
  std::vector<std::pair<KeyframeId, std::vector<MapPointId>>> associations;  // per feature
  std::vector<MapPoint> points;  // observations left empty: the associations carry them
  std::vector<MapPointId> removed_points;
  std::vector<KeyframeId> removed_keyframes;
};

// The update after a keyframe: the window around it (the keyframe and its covisible
// neighbours): their poses, associations, and every point they observe; plus what the map
// journaled as removed since the last call.
LocalMapUpdate MakeLocalMapUpdate(Map* map, KeyframeId keyframe, int revision, int queued_keyframes);

// The points just made for `keyframe` (`created`), before the rest of its mapping: them, and the
// associations of the keyframes that observe them. last_keyframe stays unset (the keyframe is not
// done) and nothing is taken from the removal journal (the update after the keyframe carries it).
LocalMapUpdate MakeNewPointsUpdate(const Map& map, KeyframeId keyframe, const std::vector<MapPointId>& created,
                                   int revision);

// Applies an update to a copy of the submap: removals first, then points, associations and
// poses; keyframes the copy does not have are ignored (they may have been culled here already).
// Returns the keyframes whose associations changed.
std::vector<KeyframeId> ApplyLocalMapUpdate(const LocalMapUpdate& update, Map* map);

// Splits an update into parts whose encoded size stays under about `max_bytes` each.
std::vector<LocalMapUpdate> SplitLocalMapUpdate(const LocalMapUpdate& update, size_t max_bytes);

}  // namespace stitch
