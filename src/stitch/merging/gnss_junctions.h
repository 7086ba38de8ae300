#pragma once
// Merged maps that no verified view connects, joined where the aircraft's GNSS puts them
// (docs/geo.md). A gust that leaves the aircraft over new ground starts a submap that may share
// no view with any other: bag-of-words can never merge it, but the receiver saw where it flew.
// Each merged map (a submap on its own is one) is placed in the merger's ENU frame by the fixes
// taken while its keyframes were flown (PlaceByGnss, robust to fixes that jump); every placed map
// then joins the largest placed one through a junction of its own kind (EdgeKind::kGnss) between
// the two submaps nearest each other in time, whose similarity is the two placements'. Views
// come first: a junction joins only maps the visual spanning forest left apart, so a verified
// connection that arrives later replaces it.

#include <map>
#include <string>
#include <vector>

#include "stitch/geo/geo_registration.h"
#include "stitch/geo/gnss_fix.h"
#include "stitch/map/submap_update.h"
#include "stitch/merging/submap_graph.h"

namespace stitch {

// Each submap's fixes (its aircraft's, over its keyframes' times), in one ENU frame.
using SubmapFixes = std::map<SubmapId, std::vector<EnuFix>>;

struct GnssJoining {
  std::vector<SubmapEdge> junctions;  // EdgeKind::kGnss, in the order they join
  // Each merged map with fixes (by its root submap): where the fixes place it, or why they do not.
  std::map<SubmapId, GeoPlacement> placements;
  // Maps the fixes place but that are not joined, by root, and why: a map whose fixes all come
  // after its aircraft's receiver was caught jumping for good in another map (a later group of
  // that map's fixes agreeing with each other on another place: PlaceByGnss's disagreement).
  std::map<SubmapId, std::string> not_joined;
};

// `placement`: the submaps' places in their merged maps as views join them (PlaceSubmaps).
// A junction's gnss_sigma_m is the two placements' standard error at it (each map's horizontal
// residual RMS over the square root of its inlier fixes, added in quadrature).
GnssJoining JoinByGnss(const std::map<SubmapId, SubmapReplica>& submaps,
                       const std::map<SubmapId, SubmapPlacement>& placement, const SubmapFixes& fixes,
                       const GeoReferenceOptions& options);

// Where a merged map lies in the ENU frame of the fixes.
struct MergedMapOnEarth {
  Sim3d enu_from_world;  // the merged map's frame into ENU: its scale is metres per map unit
  int inlier_fixes = 0;
  double horizontal_rms_m = 0.0;
};
// Each merged map (by component, as `placement` joins the submaps now, GNSS junctions included)
// that a placement by the fixes (GnssJoining::placements, by the root of the map views joined)
// puts on Earth: the placement of the part with the most inlier fixes, carried into the merged
// map's frame.
std::map<int, MergedMapOnEarth> MapsOnEarth(const std::map<SubmapId, GeoPlacement>& placements,
                                            const std::map<SubmapId, SubmapPlacement>& placement);

}  // namespace stitch
