#include "stitch/merging/gnss_junctions.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <utility>

#include "stitch/io/trajectory.h"

namespace stitch {
namespace {

// A merged map as views join it: its submaps, its keyframes in its frame, and its fixes.
struct ViewJoinedMap {
  SubmapId root;
  std::vector<SubmapId> members;
  std::vector<StampedPose> keyframes;
  std::vector<EnuFix> fixes;
};

struct TimeSpan {
  int64_t first = std::numeric_limits<int64_t>::max();
  int64_t last = std::numeric_limits<int64_t>::min();
};

// Time between two spans; 0 where they overlap.
int64_t Gap(const TimeSpan& x, const TimeSpan& y) {
  return std::max<int64_t>(0, std::max(x.first, y.first) - std::min(x.last, y.last));
}

}  // namespace

GnssJoining JoinByGnss(const std::map<SubmapId, SubmapReplica>& submaps,
                       const std::map<SubmapId, SubmapPlacement>& placement, const SubmapFixes& fixes,
                       const GeoReferenceOptions& options) {
  GnssJoining joining;
  std::map<int, ViewJoinedMap> maps;  // by component
  std::map<SubmapId, TimeSpan> spans;
  for (const auto& [id, place] : placement) {
    const auto replica = submaps.find(id);
    if (replica == submaps.end()) continue;
    ViewJoinedMap& map = maps[place.component];
    map.root = place.root;
    map.members.push_back(id);
    for (const auto& [keyframe_id, keyframe] : replica->second.map.keyframes()) {
      const Rigid3d submap_from_cam = keyframe.cam_from_world.Inverse();
      const Sim3d world_from_cam =
          place.world_from_submap * Sim3d(1.0, submap_from_cam.rotation, submap_from_cam.translation);
      map.keyframes.push_back({keyframe.t_ns, Rigid3d(world_from_cam.rotation, world_from_cam.translation)});
      TimeSpan& span = spans[id];
      span.first = std::min(span.first, keyframe.t_ns);
      span.last = std::max(span.last, keyframe.t_ns);
    }
    const auto own = fixes.find(id);
    if (own != fixes.end()) map.fixes.insert(map.fixes.end(), own->second.begin(), own->second.end());
  }
  std::map<int, Sim3d> enu_from_map;  // the placed maps, by component (the largest first)
  std::vector<int> components;
  std::vector<Trajectory> trajectories;
  for (auto& [component, map] : maps) {
    if (map.fixes.empty() || map.keyframes.empty()) continue;
    std::sort(map.fixes.begin(), map.fixes.end(), [](const EnuFix& x, const EnuFix& y) { return x.t_ns < y.t_ns; });
    map.fixes.erase(std::unique(map.fixes.begin(), map.fixes.end(),
                                [](const EnuFix& x, const EnuFix& y) { return x.t_ns == y.t_ns; }),
                    map.fixes.end());
    components.push_back(component);
    trajectories.emplace_back(map.keyframes);
  }
  std::vector<MapToPlace> to_place;
  for (size_t i = 0; i < components.size(); ++i) to_place.push_back({&trajectories[i], &maps.at(components[i]).fixes});
  std::vector<GeoPlacement> placements = PlaceMapsByGnss(to_place, options);
  for (size_t i = 0; i < components.size(); ++i) {
    if (placements[i].placed) enu_from_map[components[i]] = placements[i].enu_from_map;
    joining.placements[maps.at(components[i]).root] = std::move(placements[i]);
  }
  // A receiver caught jumping for good in one map is not trusted from then on: the maps of that
  // aircraft whose fixes all come later are not joined (with no view shared, nothing could tell
  // their offset).
  std::map<int, std::pair<int64_t, SubmapId>> distrusted;  // by aircraft: from when, found in which map
  for (const auto& [component, enu] : enu_from_map) {
    const ViewJoinedMap& map = maps.at(component);
    const GeoPlacement& placed = joining.placements.at(map.root);
    if (!placed.disagreement || placed.disagreement->first_ns <= map.fixes.front().t_ns) continue;
    auto [at, fresh] = distrusted.try_emplace(AgentNumber(map.root), placed.disagreement->first_ns, map.root);
    if (!fresh && placed.disagreement->first_ns < at->second.first)
      at->second = {placed.disagreement->first_ns, map.root};
  }
  for (auto placed = enu_from_map.begin(); placed != enu_from_map.end();) {
    const ViewJoinedMap& map = maps.at(placed->first);
    const auto found = distrusted.find(AgentNumber(map.root));
    if (found == distrusted.end() || map.fixes.front().t_ns < found->second.first) {
      ++placed;
      continue;
    }
    char why[200];
    std::snprintf(why, sizeof(why),
                  "its fixes come after the receiver jumped for good at %.1f s (found in submap %s's): not joined",
                  found->second.first * 1e-9, SubmapName(found->second.second).c_str());
    joining.not_joined[map.root] = why;
    placed = enu_from_map.erase(placed);
  }
  if (enu_from_map.size() < 2) return joining;

  const auto enu_from_submap = [&](SubmapId id) {
    const SubmapPlacement& place = placement.at(id);
    return enu_from_map.at(place.component) * place.world_from_submap;
  };
  const auto standard_error = [&](SubmapId id) {
    const GeoPlacement& placed = joining.placements.at(placement.at(id).root);
    return placed.horizontal_rms_m / std::sqrt(static_cast<double>(std::max(1, placed.inliers)));
  };
  // The largest placed map first; each other joins what is joined already through the pair of
  // submaps nearest each other in time (where the gust that parted them was).
  std::vector<SubmapId> joined = maps.at(enu_from_map.begin()->first).members;
  for (auto placed = std::next(enu_from_map.begin()); placed != enu_from_map.end(); ++placed) {
    const ViewJoinedMap& map = maps.at(placed->first);
    SubmapId nearest_a, nearest_b;
    int64_t nearest_gap = std::numeric_limits<int64_t>::max();
    for (SubmapId a : map.members) {
      if (!spans.count(a)) continue;
      for (SubmapId b : joined) {
        if (!spans.count(b)) continue;
        const int64_t gap = Gap(spans.at(a), spans.at(b));
        if (gap < nearest_gap) {
          nearest_gap = gap;
          nearest_a = a;
          nearest_b = b;
        }
      }
    }
    if (!nearest_a.valid()) continue;
    SubmapEdge junction;
    junction.kind = EdgeKind::kGnss;
    junction.a = std::min(nearest_a, nearest_b);
    junction.b = std::max(nearest_a, nearest_b);
    junction.b_from_a = enu_from_submap(junction.b).Inverse() * enu_from_submap(junction.a);
    junction.gnss_sigma_m = std::hypot(standard_error(junction.a), standard_error(junction.b));
    joining.junctions.push_back(junction);
    joined.insert(joined.end(), map.members.begin(), map.members.end());
  }
  return joining;
}

std::map<int, MergedMapOnEarth> MapsOnEarth(const std::map<SubmapId, GeoPlacement>& placements,
                                            const std::map<SubmapId, SubmapPlacement>& placement) {
  std::map<int, MergedMapOnEarth> on_earth;
  for (const auto& [root, geo] : placements) {
    const auto place = placement.find(root);
    if (!geo.placed || place == placement.end()) continue;
    const auto known = on_earth.find(place->second.component);
    if (known != on_earth.end() && known->second.inlier_fixes >= geo.inliers) continue;
    // The part's frame is its root's; the merged map places that submap at world_from_submap.
    on_earth[place->second.component] = {geo.enu_from_map * place->second.world_from_submap.Inverse(), geo.inliers,
                                         geo.horizontal_rms_m};
  }
  return on_earth;
}

}  // namespace stitch
