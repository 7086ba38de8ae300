#pragma once
// Settings of the merging algorithm (the `merger:` section of a stitch config). A light header:
// the configuration includes it without the merger's code.

#include <string>

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
  double fuse_radius_px = 3.0;    // search radius (x level scale) when fusing by projection
  bool bundle_adjustment = true;  // global bundle adjustment after fusing
  int bundle_adjustment_iterations = 10;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("fuse_points", fuse_points, "fuse the same point seen from two merged submaps into one");
    v("fuse_window", fuse_window, "covisible keyframes around each connected keyframe searched for duplicates");
    v("fuse_radius_px", fuse_radius_px, "search radius in pixels (times the level's scale) when fusing by projection");
    v("bundle_adjustment", bundle_adjustment, "global bundle adjustment of each merged map after the pose graph");
    v("bundle_adjustment_iterations", bundle_adjustment_iterations, "iterations of each global bundle adjustment pass");
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
  bool loop_closure = true;               // connected frames within a submap, away from the covisible window
  int loop_min_separation = 20;           // keyframes between a loop's two ends
  MergedMapOptions merged_map;            // fusing points and the global bundle adjustment

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
    v("loop_closure", loop_closure, "look for connected frames within each submap too (in-map loop closure)");
    v("loop_min_separation", loop_min_separation, "keyframes (by number) between the two ends of a loop");
    v("merged_map", merged_map, "fusing duplicate points and the global bundle adjustment after the pose graph");
  }
  bool Check(std::string* why) const;
};

}  // namespace stitch
