#pragma once
// Keyframes, map points and local-map updates to and from their LCM messages. Everything that
// arrives is checked (array sizes that agree, levels and positions in range, finite numbers);
// a message that fails is rejected with the reason, never half-applied.

#include <string>
#include <vector>

#include "stitch/keyframe_t.hpp"
#include "stitch/local_map_update_t.hpp"
#include "stitch/map/local_map_update.h"
#include "stitch/map/map.h"
#include "stitch/map/submap_update.h"
#include "stitch/map_point_t.hpp"
#include "stitch/submap_update_t.hpp"

namespace stitch {

stitch::map_point_t ToMessage(const MapPoint& point);
// Throws stitch::Error for a point that is not finite.
MapPoint FromMessage(const stitch::map_point_t& message, SubmapId submap);

// The keyframe's features and associations (not its image-derived caches), with `new_points`.
stitch::keyframe_t ToMessage(const Keyframe& keyframe, const Camera& camera, const std::vector<MapPoint>& new_points);

struct ReceivedKeyframe {
  Keyframe keyframe;  // keypoints, descriptors, associations, pose; caches not filled
  Camera camera;
  std::vector<MapPoint> new_points;
};
// Throws stitch::Error saying what is inconsistent (e.g. "keyframe 12: 999 descriptors for 1000 features").
ReceivedKeyframe FromMessage(const stitch::keyframe_t& message, const ScalePyramid& pyramid);

// One LCM message per part (see SplitLocalMapUpdate).
std::vector<stitch::local_map_update_t> ToMessages(const LocalMapUpdate& update, size_t max_part_bytes = 60000);
LocalMapUpdate FromMessage(const stitch::local_map_update_t& message);

// Part `index` of `count` of an update (SplitSubmapUpdate) as its message; `part.camera` must be
// set when it carries keyframes.
stitch::submap_update_t ToMessage(const SubmapUpdate& part, int32_t index, int32_t count);
// One LCM message per part (see SplitSubmapUpdate); `update.camera` must be set when it carries
// keyframes.
std::vector<stitch::submap_update_t> ToMessages(const SubmapUpdate& update, size_t max_part_bytes = 60000);
// The messages of several updates, in order (what a mapper publishes over a flight).
std::vector<stitch::submap_update_t> ToMessages(const std::vector<SubmapUpdate>& updates);
// Throws stitch::Error saying what is inconsistent.
SubmapUpdate FromMessage(const stitch::submap_update_t& message, const ScalePyramid& pyramid);

}  // namespace stitch
