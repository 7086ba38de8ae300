#include "stitch/merging/merged_map.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <iterator>
#include <limits>
#include <optional>
#include <set>

#include "stitch/map/matcher.h"
#include "stitch/util/options.h"

namespace stitch {
namespace {

// A merged point's id after earlier fusions (ReplacePoint removes the duplicate's id).
MapPointId Resolve(const std::map<MapPointId, MapPointId>& replaced, MapPointId id) {
  for (auto it = replaced.find(id); it != replaced.end(); it = replaced.find(id)) id = it->second;
  return id;
}

// Makes points `a` and `b` one (the one with fewer observations goes) and records which went.
void FusePair(Map* map, MapPointId a, MapPointId b, std::map<MapPointId, MapPointId>* replaced) {
  const MapPoint* point_a = map->FindPoint(a);
  const MapPoint* point_b = map->FindPoint(b);
  const bool keep_a = point_a->observations.size() >= point_b->observations.size();
  const MapPointId keep = keep_a ? a : b, duplicate = keep_a ? b : a;
  map->ReplacePoint(duplicate, keep);
  (*replaced)[duplicate] = keep;
}

void RefreshGeometry(Map* map) {
  std::vector<MapPointId> ids;
  ids.reserve(map->num_points());
  for (const auto& [id, point] : map->points()) ids.push_back(id);
  for (MapPointId id : ids) map->UpdatePointGeometry(id);
}

// The submap's keyframe `id` and its best covisible keyframes. Where its mapper has culled `id`
// since, the keyframes that see most of the connection's matched points on this side (`first`:
// the pairs' first points; they outlive the keyframe) instead.
std::vector<KeyframeId> Window(const Map& submap, KeyframeId id,
                               const std::vector<std::pair<MapPointId, MapPointId>>& point_pairs, bool first,
                               int size) {
  if (submap.FindKeyframe(id)) {
    std::vector<KeyframeId> window = submap.BestCovisible(id, size);
    window.push_back(id);
    return window;
  }
  std::map<KeyframeId, int> seen;
  for (const auto& pair : point_pairs) {
    const MapPoint* point = submap.FindPoint(first ? pair.first : pair.second);
    if (!point) continue;
    for (const auto& [keyframe, feature] : point->observations) ++seen[keyframe];
  }
  std::vector<std::pair<int, KeyframeId>> by_count;
  for (const auto& [keyframe, count] : seen) by_count.emplace_back(-count, keyframe);
  std::sort(by_count.begin(), by_count.end());
  std::vector<KeyframeId> window;
  for (size_t i = 0; i < by_count.size() && window.size() < static_cast<size_t>(size) + 1; ++i) {
    window.push_back(by_count[i].second);
  }
  return window;
}

// Whether both keyframes of `c` are still in their submaps (the mappers cull keyframes).
bool BothKeyframesRemain(const std::map<SubmapId, SubmapReplica>& submaps, const ConnectedFrame& c) {
  return submaps.at(SubmapOf(c.keyframe_a)).map.FindKeyframe(c.keyframe_a) &&
         submaps.at(SubmapOf(c.keyframe_b)).map.FindKeyframe(c.keyframe_b);
}

// Observations of a point of one submap by a keyframe of another, by the pair (smaller id
// first): all, and those within `chi2_threshold` of their point where the map has them now.
struct JoiningCount {
  int all = 0, agreeing = 0;
};
std::map<std::pair<SubmapId, SubmapId>, JoiningCount> CountJoiningObservations(const Map& map,
                                                                               const PinholeIntrinsics& k,
                                                                               double chi2_threshold) {
  std::map<std::pair<SubmapId, SubmapId>, JoiningCount> counts;
  for (const auto& [id, point] : map.points()) {
    const SubmapId from = SubmapOf(id);
    for (const auto& [keyframe, feature] : point.observations) {
      const SubmapId by = SubmapOf(keyframe);
      if (by == from) continue;
      JoiningCount& count = counts[SubmapPair(from, by)];
      ++count.all;
      const Keyframe* observer = map.FindKeyframe(keyframe);
      count.agreeing +=
          observer && ObservationErrors(*observer, feature, point.position, k, map.pyramid()).second <= chi2_threshold;
    }
  }
  return counts;
}

}  // namespace

PositionPriors PriorsFromFixes(const Map& map, const FixesOnEarth& on_earth) {
  PositionPriors priors;
  if (!on_earth.fixes || !on_earth.georeference) return priors;
  const GeoReferenceOptions& geo = *on_earth.georeference;
  priors.outlier_chi2 = geo.outlier_chi2;
  const Sim3d& enu_from_world = on_earth.enu_from_world;
  const Sim3d world_from_enu = enu_from_world.Inverse();
  const Eigen::Vector3d antenna_in_camera =
      Eigen::Vector3d(geo.antenna_x_m, geo.antenna_y_m, geo.antenna_z_m) / enu_from_world.scale;
  const Eigen::Matrix3d to_enu = enu_from_world.scale * enu_from_world.rotation.toRotationMatrix();
  const auto max_gap_ns = static_cast<int64_t>(geo.max_interpolation_gap_s * 1e9);
  const auto offset_ns = static_cast<int64_t>(std::llround(geo.time_offset_s * 1e9));
  std::map<SubmapId, std::map<int64_t, KeyframeId>> keyframes_by_time;  // of each submap
  for (const auto& [id, keyframe] : map.keyframes()) keyframes_by_time[SubmapOf(id)].emplace(keyframe.t_ns, id);
  for (const auto& [submap, timeline] : keyframes_by_time) {
    const auto fixes = on_earth.fixes->find(submap);
    if (fixes == on_earth.fixes->end()) continue;
    for (const EnuFix& fix : fixes->second) {
      if (!(fix.horizontal_sigma_m > 0) || !(fix.vertical_sigma_m > 0)) continue;
      constexpr int64_t kMax = std::numeric_limits<int64_t>::max(), kMin = std::numeric_limits<int64_t>::min();
      if (offset_ns > 0 ? fix.t_ns > kMax - offset_ns : fix.t_ns < kMin - offset_ns) continue;
      const int64_t t = fix.t_ns + offset_ns;
      auto after = timeline.lower_bound(t);
      if (after == timeline.end()) continue;
      PositionPrior prior;
      if (after->first == t) {
        prior.before = prior.after = after->second;
      } else {
        if (after == timeline.begin() || after->first - std::prev(after)->first > max_gap_ns) continue;
        const auto before = std::prev(after);
        prior.before = before->second;
        prior.after = after->second;
        prior.weight_after = static_cast<double>(t - before->first) / static_cast<double>(after->first - before->first);
      }
      prior.antenna_in_camera = antenna_in_camera;
      prior.position = world_from_enu * fix.enu;
      prior.sqrt_information =
          Eigen::Vector3d(1.0 / fix.horizontal_sigma_m, 1.0 / fix.horizontal_sigma_m, 1.0 / fix.vertical_sigma_m)
              .asDiagonal() *
          to_enu;
      priors.priors.push_back(prior);
    }
  }
  return priors;
}

MergedMap AssembleMergedMap(const std::map<SubmapId, SubmapReplica>& submaps,
                            const std::map<SubmapId, SubmapPlacement>& placement,
                            const std::map<KeyframeId, Sim3d>& keyframe_poses,
                            const std::vector<ConnectedFrame>& connections, int component, const ScalePyramid& pyramid,
                            const PinholeIntrinsics& intrinsics, const MergedMapOptions& options,
                            const FixesOnEarth* on_earth) {
  CheckOptions(options, "merged_map");
  MergedMap merged(pyramid);
  merged.component = component;
  // The first keyframe of each anchor submap holds the frame during adjustment: the root's, and
  // where a GNSS junction joins parts that no view connects, each part's.
  std::map<SubmapId, KeyframeId> anchors;
  for (const auto& [submap_id, place] : placement) {
    if (place.component != component) continue;
    const auto found = submaps.find(submap_id);
    if (found == submaps.end()) continue;
    const Map& submap = found->second.map;
    std::map<KeyframeId, Sim3d> world_from_cam;
    for (const auto& [id, keyframe] : submap.keyframes()) {
      const auto refined = keyframe_poses.find(id);
      const Rigid3d submap_from_cam = keyframe.cam_from_world.Inverse();
      world_from_cam[id] =
          refined != keyframe_poses.end()
              ? refined->second
              : place.world_from_submap * Sim3d(1.0, submap_from_cam.rotation, submap_from_cam.translation);
      if (submap_id == place.Anchor() && (!anchors[submap_id].valid() || id < anchors[submap_id])) {
        anchors[submap_id] = id;
      }
    }
    // Points move with their reference keyframe (the pose graph moved each keyframe on its own).
    for (const auto& [id, point] : submap.points()) {
      KeyframeId reference = point.reference_keyframe;
      if (!world_from_cam.count(reference)) {
        reference = KeyframeId();
        for (const auto& [kf, feature] : point.observations) {
          if (world_from_cam.count(kf)) {
            reference = kf;
            break;
          }
        }
      }
      if (!reference.valid()) continue;
      MapPoint copy = point;
      copy.observations.clear();
      copy.reference_keyframe = reference;
      copy.position = world_from_cam.at(reference) * (submap.FindKeyframe(reference)->cam_from_world * point.position);
      merged.map.AddPoint(std::move(copy));
    }
    for (const auto& [id, keyframe] : submap.keyframes()) {
      Keyframe copy = UnlinkedCopy(keyframe);
      const Sim3d& pose = world_from_cam.at(id);
      copy.cam_from_world = Rigid3d(pose.rotation, pose.translation).Inverse();
      merged.map.AddKeyframe(std::move(copy));
      merged.keyframe_poses[id] = pose;
    }
  }
  if (merged.map.num_keyframes() == 0) return merged;
  RefreshGeometry(&merged.map);

  // The fixes' priors hang on keyframes and times, which fusing does not change: made once.
  const std::optional<PositionPriors> priors =
      on_earth && options.gnss_in_adjustment ? std::optional(PriorsFromFixes(merged.map, *on_earth)) : std::nullopt;
  const auto adjust = [&] {
    std::vector<KeyframeId> fixed;
    for (const auto& [submap, first] : anchors) {
      if (first.valid()) fixed.push_back(first);
    }
    if (!options.bundle_adjustment || fixed.empty()) return;
    std::vector<KeyframeId> free;
    for (const auto& [id, keyframe] : merged.map.keyframes()) {
      if (std::find(fixed.begin(), fixed.end(), id) == fixed.end()) free.push_back(id);
    }
    const size_t max_free = options.bundle_adjustment_max_free_keyframes;
    if (max_free > 0 && free.size() > max_free) {  // the newest move; older ones hold their points
      const auto newer = [&](KeyframeId a, KeyframeId b) {
        const int64_t ta = merged.map.FindKeyframe(a)->t_ns, tb = merged.map.FindKeyframe(b)->t_ns;
        return ta != tb ? ta > tb : b < a;
      };
      std::nth_element(free.begin(), free.begin() + max_free, free.end(), newer);
      free.resize(max_free);
    }
    BundleAdjustmentOptions ba;
    ba.iterations = options.bundle_adjustment_iterations;
    ba.refine_iterations = options.bundle_adjustment_iterations;
    const BundleAdjustmentReport report =
        BundleAdjust(&merged.map, free, fixed, intrinsics, ba, {}, priors ? &*priors : nullptr);
    if (merged.bundle_adjustment.keyframes_free == 0) {
      merged.bundle_adjustment = report;
    } else {  // the second pass: keep the first pass's initial error for the report
      const double initial = merged.bundle_adjustment.initial_rms_px;
      const int removed = merged.bundle_adjustment.outliers_removed;
      merged.bundle_adjustment = report;
      merged.bundle_adjustment.initial_rms_px = initial;
      merged.bundle_adjustment.outliers_removed += removed;
    }
    RefreshGeometry(&merged.map);
  };

  std::vector<const ConnectedFrame*> inside;  // connections within this merged map
  for (const ConnectedFrame& c : connections) {
    const auto a = placement.find(SubmapOf(c.keyframe_a)), b = placement.find(SubmapOf(c.keyframe_b));
    if (a != placement.end() && b != placement.end() && a->second.component == component &&
        b->second.component == component) {
      inside.push_back(&c);
    }
  }
  std::map<MapPointId, MapPointId> replaced;
  if (options.fuse_points) {
    for (const ConnectedFrame* connection : inside) {
      const ConnectedFrame& c = *connection;
      // A connection verified before its keyframe was culled cannot be verified again: its
      // pairs may be of points that have moved apart since, so only projection fuses around it.
      if (!BothKeyframesRemain(submaps, c)) continue;
      for (const auto& [a, b] : c.point_pairs) {
        const MapPointId pa = Resolve(replaced, a), pb = Resolve(replaced, b);
        if (pa == pb || !merged.map.FindPoint(pa) || !merged.map.FindPoint(pb)) continue;
        FusePair(&merged.map, pa, pb, &replaced);
        ++merged.points_fused_by_connection;
      }
    }
  }
  // What fusing joins, and what each adjustment leaves of it (the check after placement).
  const double chi2 = BundleAdjustmentOptions().chi2_threshold;
  for (const auto& [pair, count] : CountJoiningObservations(merged.map, intrinsics, chi2)) {
    merged.junctions[pair].joined += count.all;
  }
  // After each adjustment: what is left of the joining observations (`left`: to tell what
  // fusing by projection adds next) and how many of them are within the bound (`kept`).
  std::map<std::pair<SubmapId, SubmapId>, int> left;
  const auto count_kept = [&] {
    left.clear();
    for (auto& [pair, junction] : merged.junctions) junction.kept = 0;
    for (const auto& [pair, count] : CountJoiningObservations(merged.map, intrinsics, chi2)) {
      merged.junctions[pair].kept = count.agreeing;
      left[pair] = count.all;
    }
  };
  adjust();
  count_kept();
  if (options.fuse_points) {
    // Around each connection, each side's points are searched in the other side's keyframes.
    std::map<std::pair<SubmapId, SubmapId>, std::pair<std::set<KeyframeId>, std::set<KeyframeId>>> windows;
    for (const ConnectedFrame* connection : inside) {
      const ConnectedFrame& c = *connection;
      const SubmapId a = SubmapOf(c.keyframe_a), b = SubmapOf(c.keyframe_b);
      auto& [side_a, side_b] = windows[{a, b}];
      for (KeyframeId id : Window(submaps.at(a).map, c.keyframe_a, c.point_pairs, true, options.fuse_window)) {
        side_a.insert(id);
      }
      for (KeyframeId id : Window(submaps.at(b).map, c.keyframe_b, c.point_pairs, false, options.fuse_window)) {
        side_b.insert(id);
      }
    }
    const auto points_of = [&](const std::set<KeyframeId>& keyframes) {
      std::set<MapPointId> points;
      for (KeyframeId id : keyframes) {
        const Keyframe* keyframe = merged.map.FindKeyframe(id);
        if (!keyframe) continue;
        for (MapPointId p : keyframe->points) {
          if (p.valid() && merged.map.FindPoint(p)) points.insert(p);
        }
      }
      return std::vector<MapPointId>(points.begin(), points.end());
    };
    for (const auto& [pair, sides] : windows) {
      const auto& [side_a, side_b] = sides;
      // Two submaps' first placement can be pixels off; a loop's ends are of one mapper's map.
      const FuseSearch search = pair.first != pair.second ? FuseSearch::kWholeRadius : FuseSearch::kWithinNoise;
      for (const auto& [into, from] : {std::make_pair(&side_a, &side_b), std::make_pair(&side_b, &side_a)}) {
        const std::vector<MapPointId> candidates = points_of(*from);
        for (KeyframeId id : *into) {
          merged.points_fused_by_projection +=
              Fuse(&merged.map, id, candidates, intrinsics, options.fuse_radius_px, search);
        }
      }
    }
    for (const auto& [pair, count] : CountJoiningObservations(merged.map, intrinsics, chi2)) {
      Junction& junction = merged.junctions[pair];
      junction.joined += std::max(0, count.all - left[pair]);  // what fusing by projection added
    }
    adjust();
    count_kept();
  }
  // Keyframes keep their submap's scale (frames between keyframes follow it); rotation and
  // position come from the adjustment.
  for (auto& [id, pose] : merged.keyframe_poses) {
    const Keyframe* keyframe = merged.map.FindKeyframe(id);
    if (!keyframe) continue;
    const Rigid3d world_from_cam = keyframe->cam_from_world.Inverse();
    pose = Sim3d(pose.scale, world_from_cam.rotation, world_from_cam.translation);
  }
  return merged;
}

std::vector<DoubtedEdge> CheckJunctions(const MergedMap& merged, const std::vector<SubmapEdge>& tree,
                                        const AcceptanceOptions& options) {
  // Only the merges inside `merged` have had their junctions fused; a merge in another merged map
  // (the largest is the one assembled) is judged when that map is.
  std::set<SubmapId> inside;
  for (const auto& [keyframe, pose] : merged.keyframe_poses) inside.insert(SubmapOf(keyframe));
  std::vector<DoubtedEdge> doubted;
  for (const SubmapEdge& edge : tree) {
    // A GNSS junction joins what shares no view: no points to fuse, nothing to check.
    if (edge.kind != EdgeKind::kVisual || !inside.count(edge.a) || !inside.count(edge.b)) continue;
    const auto found = merged.junctions.find(SubmapPair(edge.a, edge.b));
    const Junction j = found != merged.junctions.end() ? found->second : Junction();
    char why[200];
    if (j.joined < options.min_junction_observations) {
      std::snprintf(why, sizeof(why),
                    "after placement fusing found too few points of either submap in the other (%d observations join "
                    "them, needs %d)",
                    j.joined, options.min_junction_observations);
    } else if (j.kept < options.min_junction_kept * j.joined) {
      std::snprintf(why, sizeof(why),
                    "after placement the bundle adjustment kept %d of the %d observations joining the submaps (%.1f%%, "
                    "needs %.1f%%)",
                    j.kept, j.joined, 100.0 * j.kept / j.joined, 100.0 * options.min_junction_kept);
    } else {
      continue;
    }
    doubted.push_back({edge, why});
  }
  return doubted;
}

}  // namespace stitch
