#pragma once
// Settings of the merging algorithm (the `merger:` section of a stitch config). A light header:
// the configuration includes it without the merger's code.

#include <string>

#include "stitch/geo/geo_registration.h"
#include "stitch/map/map_export.h"
#include "stitch/mosaic/mosaic_options.h"

namespace stitch {

// Weights of the connection strength between two submaps, C = frames * F + points * M +
// angle * theta_m^2 (F: connected frames, M: map points in them, theta_m: their median
// intersection angle in degrees, capped at 45). The method's values are 1, 0.1, 0.1.
struct ConnectionWeights {
  double frames = 1.0;
  double points = 0.1;
  double angle = 0.1;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("frames", frames, "weight of F, the connected frames between the two submaps");
    v("points", points, "weight of M, the map points that agree in those connected frames");
    v("angle", angle, "weight of theta_m^2, their median intersection angle in degrees (capped at 45)");
  }
  bool Check(std::string* why) const;
};

struct MergedMapOptions {
  bool fuse_points = true;        // fuse duplicates across submaps
  int fuse_window = 10;           // covisible keyframes taken around each connected keyframe
  double fuse_radius_px = 4.0;    // search radius (x level scale) when fusing by projection
  bool bundle_adjustment = true;  // global bundle adjustment after fusing
  int bundle_adjustment_iterations = 10;
  // A long flight: at most this many keyframes move in the bundle adjustment, the newest (the
  // pose graph has placed all; older keyframes that see their points hold them); 0: all. Without
  // it the adjustment of a 20,000-frame survey's map grows to minutes per submap.
  int bundle_adjustment_max_free_keyframes = 400;
  // Where the aircraft's fixes put the map on Earth, they hold its keyframes' antennas in the
  // adjustment, each weighted by its stated accuracy (docs/geo.md).
  bool gnss_in_adjustment = true;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("fuse_points", fuse_points, "fuse the same point seen from two merged submaps into one");
    v("fuse_window", fuse_window, "covisible keyframes around each connected keyframe searched for duplicates");
    v("fuse_radius_px", fuse_radius_px,
      "search radius in pixels (times the level's scale) when fusing by projection: between two submaps the whole "
      "radius (their first placement can be a few pixels off), around a loop only within the noise bound");
    v("bundle_adjustment", bundle_adjustment, "global bundle adjustment of each merged map after the pose graph");
    v("bundle_adjustment_iterations", bundle_adjustment_iterations, "iterations of each global bundle adjustment pass");
    v("bundle_adjustment_max_free_keyframes", bundle_adjustment_max_free_keyframes,
      "keyframes the adjustment moves at most, the newest (older ones that see their points hold them; 0: all)");
    v("gnss_in_adjustment", gnss_in_adjustment,
      "where the aircraft's GNSS fixes place the merged map, each fix holds the antenna where it says in the global "
      "bundle adjustment, weighted by its stated accuracy, outliers set aside: the fixes bend a long map's scale "
      "drift out (needs merger.georeference.enabled and merger.join_by_gnss)");
  }
  bool Check(std::string* why) const;
};

// The checks a connection and an edge must pass before they may place a submap
// (docs/merger.md, "Acceptance"): a connection whose points cannot pin a rotation, an edge with
// one connected frame or whose connected frames disagree among themselves, waits.
struct AcceptanceOptions {
  double min_line_ratio = 0.05;            // a connection's points in 3D: middle / largest principal spread
  double min_bearing_spread = 0.01;        // ...their bearings in each image: smaller principal spread (rad)
  int min_connected_frames = 2;            // agreeing connected frames an edge needs
  double min_agreement = 0.6;              // share of the pair's points whose rotation agrees with the edge's Sim3
  bool reverify_stale_connections = true;  // verify connections again on newer points before each refinement
  double max_missing_keyframes = 0.25;     // share of a submap's keyframes its copy may lack and still be placed
  // Checked after placement (CheckJunctions): a merge whose junction the global adjustment
  // cannot hold is rolled back.
  double min_junction_kept = 0.5;      // share of the observations joining two submaps the adjustment must keep
  int min_junction_observations = 30;  // joining observations a merge needs (fewer: the points do not confirm it)

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("min_line_ratio", min_line_ratio,
      "a connected frame whose agreeing points lie closer to a line than this (middle over largest principal "
      "spread in 3D, of the 80% nearest their median) is refused: nothing pins the rotation about that line");
    v("min_bearing_spread", min_bearing_spread,
      "a connected frame whose points are seen within a narrower spread of directions than this (radians, the "
      "smaller principal spread in either image) is refused: near-parallel rays do not pin the rotation");
    v("min_connected_frames", min_connected_frames,
      "agreeing connected frames an edge needs before it may merge two submaps (one can be one lucky place)");
    v("min_agreement", min_agreement,
      "share of a pair's verified map points whose connected frames' rotation must agree with the edge's Sim3; "
      "below it the pair's connected frames point two ways and the edge waits");
    v("reverify_stale_connections", reverify_stale_connections,
      "before each refinement, verify again the connected frames found on older points of their submaps");
    v("max_missing_keyframes", max_missing_keyframes,
      "a submap whose copy lacks more than this share of the keyframes its manifest lists (the link has not "
      "brought them) is placed by no edge until they arrive: what it holds may be early, unrefined points");
    v("min_junction_kept", min_junction_kept,
      "checked after placement: share of the observations that fusing made between two merged submaps the global "
      "bundle adjustment must keep (it drops those its points and keyframes cannot agree on); below it the merge is "
      "rolled back and its edge waits for more connected frames (0: not checked)");
    v("min_junction_observations", min_junction_observations,
      "checked after placement: observations joining two merged submaps a merge needs (a point of one seen by a "
      "keyframe of the other, made by fusing); fewer, and no points confirm where the merge put them: it is rolled "
      "back (0: none needed)");
  }
  bool Check(std::string* why) const;
};

struct MergerOptions {
  double min_connection_strength = 10.0;  // C needed for two submaps to merge
  ConnectionWeights connection_weights;   // the weights of F, M and theta^2 in C
  int max_candidates = 3;                 // connected-frame candidates verified per keyframe
  int min_matches = 12;                   // descriptor matches with map points to try a Sim3
  int candidate_window = 5;               // covisible keyframes of a candidate whose points count when it has too few
  bool match_by_projection = true;        // when too few matches agree, look for more by projection (see merger.md)
  double match_ratio = 0.75;              // best / second-best descriptor distance
  int sim3_min_inliers = 20;              // map points agreeing with the Sim3 for a connected frame
  int relocalization_min_inliers = 50;    // points that confirm a keyframe relocalized in the other submap (0: off)
  bool request_resends = true;            // ask the mapper again for what the link lost
  double resend_interval_s = 1.0;         // between two requests for one submap
  double live_outputs_interval_s = 2.0;   // between two writes of the ground's trajectory.tum
  int map_cloud_points = 100000;          // points of <station>/MAP_CLOUD for the viewer (0: not published)
  bool loop_closure = true;               // connected frames within a submap, away from the covisible window
  int loop_min_separation = 20;           // keyframes between a loop's two ends
  MergedMapOptions merged_map;            // fusing points and the global bundle adjustment
  AcceptanceOptions acceptance;           // checks before a connection or an edge may place a submap
  MapExportOptions map_export;            // what of the merged map goes into map.ply
  GeoReferenceOptions georeference;       // each map placed on Earth by the aircraft's GNSS fixes
  MosaicOptions mosaic;                   // the largest map's orthomosaic (live, and stitch mosaic's)
  bool join_by_gnss = true;               // merged maps no view connects joined where GNSS places them
  bool save_map = true;                   // map.stitchmap: the largest merged map at the end
  std::string prior_map;                  // a saved map the flight's submaps merge into (empty: none)

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("min_connection_strength", min_connection_strength,
      "connection strength C = F + 0.1 M + 0.1 theta^2 needed to merge two submaps");
    v("connection_weights", connection_weights,
      "weights of the connection strength C = frames F + points M + angle theta^2");
    v("max_candidates", max_candidates, "connected-frame candidates verified per keyframe");
    v("min_matches", min_matches, "descriptor matches between map points needed to try a Sim3");
    v("candidate_window", candidate_window,
      "when a candidate holds too few matching points, its best covisible keyframes whose points count too (0: none)");
    v("match_ratio", match_ratio, "best / second-best descriptor distance for a match");
    v("match_by_projection", match_by_projection,
      "when too few matches agree with a Sim3, search more by projecting with a first guess");
    v("sim3_min_inliers", sim3_min_inliers, "map points that must agree with the Sim3 of a connected frame");
    v("relocalization_min_inliers", relocalization_min_inliers,
      "when no Sim3 reprojects well (little parallax), points that must confirm the keyframe relocalized in the other "
      "submap (0: off)");
    v("request_resends", request_resends,
      "ask the mapper (on <agent>/SUBMAP_REQUEST) for keyframes and final states the link lost");
    v("resend_interval_s", resend_interval_s, "seconds between two requests for one submap");
    v("live_outputs_interval_s", live_outputs_interval_s,
      "seconds between two writes of the ground's per-frame trajectory (trajectory.tum) during the flight; the map "
      "and the tables are written at every refinement (0: the trajectory only at refinements and at the end)");
    v("map_cloud_points", map_cloud_points,
      "points at most in <station>/MAP_CLOUD, the merged maps' points for the live viewer, published at every "
      "refinement and at most every 10 s while submaps grow (0: not published)");
    v("loop_closure", loop_closure, "look for connected frames within each submap too (in-map loop closure)");
    v("loop_min_separation", loop_min_separation, "keyframes (by number) between the two ends of a loop");
    v("merged_map", merged_map, "fusing duplicate points and the global bundle adjustment after the pose graph");
    v("acceptance", acceptance, "checks a connected frame and an edge must pass before they may place a submap");
    v("map_export", map_export,
      "what of the merged map goes into map.ply (everything, gross outliers included, goes into map_raw.ply)");
    v("mosaic", mosaic,
      "the largest map's orthomosaic: kept during the flight (mosaic_live.tif) and made after it (stitch mosaic, "
      "ortho.tif)");
    v("georeference", georeference,
      "each map placed on Earth by the aircraft's GNSS fixes (gnss.csv in the run folder), its trajectory in WGS84 "
      "(geo/)");
    v("join_by_gnss", join_by_gnss,
      "during the flight, join the merged maps that no verified view connects where the aircraft's GNSS fixes place "
      "them (a junction of its own kind; needs georeference.enabled)");
    v("save_map", save_map,
      "at the end, write the largest merged map as map.stitchmap, for a later flight's --map (docs/map-file.md)");
    v("prior_map", prior_map,
      "a saved map (.stitchmap) the flight's submaps merge into, as a submap of its own whose frame is the merged "
      "map's (stitch run --map; empty: none)");
  }
  bool Check(std::string* why) const;
};

}  // namespace stitch
