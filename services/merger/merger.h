#pragma once
// The merger's algorithm (no LCM here; MergerService carries it over the bus), DESIGN.md steps
// 2-4: it keeps a copy of every submap from the mappers' updates; for each new keyframe of a
// submap it retrieves connected frames in the other submaps with the adaptive thresholds
// k = N1/N0 and l = S1/S0, verifies each by matching map points and a Sim3, and from the
// verified connections builds the submap graph, whose minimum spanning tree decides the merges.
// One owner thread; not thread-safe.

#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "services/merger/merged_map.h"
#include "services/merger/submap_graph.h"
#include "stitch/estimators/sim3_estimation.h"
#include "stitch/features/keyframe_database.h"
#include "stitch/features/vocabulary.h"
#include "stitch/map/frame.h"
#include "stitch/map/submap_update.h"

namespace stitch {

struct MergerOptions {
  double min_connection_strength = 10.0;  // C needed for two submaps to merge
  int max_candidates = 3;                 // connected-frame candidates verified per keyframe
  int min_matches = 12;                   // descriptor matches with map points to try a Sim3
  bool match_by_projection = true;        // when too few matches agree, look for more by projection (see merger.md)
  double match_ratio = 0.75;              // best / second-best descriptor distance
  int sim3_min_inliers = 20;              // map points agreeing with the Sim3 for a connected frame
  bool request_resends = true;            // ask the mapper again for what the link lost
  double resend_interval_s = 1.0;         // between two requests for one submap
  bool loop_closure = true;               // connected frames within a submap, away from the covisible window
  int loop_min_separation = 20;           // keyframes between a loop's two ends
  MergedMapOptions merged_map;            // fusing points and the global bundle adjustment

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("min_connection_strength", min_connection_strength, "connection strength C = F + 0.1 M + 0.1 theta^2 needed to merge two submaps");
    v("max_candidates", max_candidates, "connected-frame candidates verified per keyframe");
    v("min_matches", min_matches, "descriptor matches between map points needed to try a Sim3");
    v("match_ratio", match_ratio, "best / second-best descriptor distance for a match");
    v("match_by_projection", match_by_projection, "when too few matches agree with a Sim3, search more by projecting with a first guess");
    v("sim3_min_inliers", sim3_min_inliers, "map points that must agree with the Sim3 of a connected frame");
    v("request_resends", request_resends,
      "ask the mapper (on <agent>/SUBMAP_REQUEST) for keyframes and final states the link lost");
    v("resend_interval_s", resend_interval_s, "seconds between two requests for one submap");
    v("loop_closure", loop_closure, "look for connected frames within each submap too (in-map loop closure)");
    v("loop_min_separation", loop_min_separation, "keyframes (by number) between the two ends of a loop");
    v("merged_map", merged_map, "fusing duplicate points and the global bundle adjustment after the pose graph");
  }
  bool Check(std::string* why) const;
};

// One connected-frame query, as the method's thresholds need to be studied.
struct RetrievalRecord {
  KeyframeId keyframe, previous, nearby;
  int n0 = 0, n1 = 0;        // words shared with the previous / the ~50%-overlap keyframe
  double s0 = 0, s1 = 0;     // BoW scores with them
  double k = 0, l = 0;       // N1/N0 and S1/S0
  int shared_word_candidates = 0;   // frames in other submaps passing k
  std::vector<KeyframeId> candidates;  // ...then passing l (verified in this order, at most max_candidates)
  std::vector<KeyframeId> connected;   // verified
  // Per candidate, then per loop candidate: descriptor matches, Sim3 inliers (0 if not tried).
  std::vector<std::pair<int, int>> verification;
  std::vector<KeyframeId> loop_candidates;  // in the same submap, outside the covisible window
  std::vector<KeyframeId> loops;            // verified
  std::string skipped;       // why there was no query (first keyframe, no other submap...)
};

class Merger {
 public:
  // `vocabulary` must outlive the merger.
  Merger(const MergerOptions& options, const Vocabulary* vocabulary, const ScalePyramid& pyramid);

  // Applies one update (or part) from a mapper; its new keyframes are queried and verified.
  // Returns the keyframes the submap's manifest lists but this copy lacks.
  std::vector<KeyframeId> Apply(const SubmapUpdate& update);

  struct Graph {
    std::vector<SubmapEdge> edges;  // every pair of submaps with verified connections
    std::vector<SubmapEdge> tree;   // Kruskal's choice, in merging order
    std::map<SubmapId, SubmapPlacement> placement;
    // With `refine`: every keyframe's world_from_cam in its merged map after the Sim3 pose-graph
    // optimization over all verified connections (not only the tree's).
    std::map<KeyframeId, Sim3d> keyframe_poses;
    std::vector<ConnectedFrame> agreeing;  // with `refine`: the connections and loops the pose graph used
    int loops_used = 0;                    // of those, loops (both ends in one submap)
  };
  Graph Solve(bool refine = false) const;

  const std::map<SubmapId, SubmapReplica>& submaps() const { return submaps_; }
  const std::vector<ConnectedFrame>& connections() const { return connections_; }
  const std::vector<ConnectedFrame>& loops() const { return loops_; }  // both ends in one submap
  const std::vector<RetrievalRecord>& retrievals() const { return retrievals_; }
  const MergerOptions& options() const { return options_; }

 private:
  void Prepare(SubmapReplica* replica, Keyframe* keyframe);
  RetrievalRecord Retrieve(const SubmapReplica& replica, const Keyframe& keyframe);
  void RetrieveLoops(const SubmapReplica& replica, const Keyframe& keyframe, RetrievalRecord* record);
  // `matches` / `inliers` (optional) receive the counts whatever the outcome.
  std::optional<ConnectedFrame> Verify(const SubmapReplica& a, const Keyframe& keyframe_a, const SubmapReplica& b,
                                       const Keyframe& keyframe_b, int* matches, int* inliers) const;
  std::optional<Sim3Estimate> VerifyByProjection(const SubmapReplica& a, const Keyframe& keyframe_a, const SubmapReplica& b,
                                                 const Keyframe& keyframe_b, const std::vector<std::pair<int, int>>& matches,
                                                 std::vector<Sim3Correspondence>* pairs,
                                                 std::vector<std::pair<MapPointId, MapPointId>>* point_ids,
                                                 int* inlier_count) const;
  const Undistorter& UndistorterFor(const Camera& camera);
  std::map<KeyframeId, Sim3d> RefineKeyframePoses(const std::map<SubmapId, SubmapPlacement>& placement, Graph* graph) const;
  // Loops confirmed by another loop between the same places with the same correction.
  std::vector<ConnectedFrame> ConfirmedLoops() const;

  MergerOptions options_;
  const Vocabulary* vocabulary_;
  ScalePyramid pyramid_;
  std::map<SubmapId, SubmapReplica> submaps_;
  std::map<std::string, Undistorter> undistorters_;  // by camera description
  KeyframeDatabase database_;
  std::set<KeyframeId> prepared_;                    // keyframes with undistorted points and BoW
  std::vector<ConnectedFrame> connections_;
  std::vector<ConnectedFrame> loops_;
  std::vector<RetrievalRecord> retrievals_;
};

}  // namespace stitch
