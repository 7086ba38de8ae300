#pragma once
// The merger's algorithm (no LCM here; MergerService carries it over the bus), docs/method.md,
// steps 2-4: it keeps a copy of every submap from the mappers' updates; for each new keyframe of a
// submap it retrieves connected frames in the other submaps with the adaptive thresholds
// k = N1/N0 and l = S1/S0, verifies each by matching map points and a Sim3, and from the
// verified connections builds the submap graph, whose minimum spanning tree decides the merges.
// One owner thread; not thread-safe.

#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "stitch/estimators/sim3_estimation.h"
#include "stitch/features/keyframe_database.h"
#include "stitch/features/vocabulary.h"
#include "stitch/map/frame.h"
#include "stitch/map/submap_update.h"
#include "stitch/merging/gnss_junctions.h"
#include "stitch/merging/merged_map.h"
#include "stitch/merging/merger_options.h"
#include "stitch/merging/submap_graph.h"
#include "stitch/records/merger_records.h"

namespace stitch {

// The geometry of a verified connection's agreeing points (`inlier` of `pairs`).
ConnectionGeometry MeasureConnectionGeometry(const std::vector<Sim3Correspondence>& pairs,
                                             const std::vector<char>& inlier, const Sim3d& b_from_a,
                                             const Rigid3d& cam_b_from_b, const PinholeIntrinsics& k);

// The keyframes a submap's copy lacks of those its manifest lists (lost or still on the link).
SubmapCompleteness CompletenessOf(const SubmapReplica& replica);

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
    // With `refine`: the connections and loops the pose graph used, and the connections whose
    // keyframe was culled that agree with the placement (for fusing around them).
    std::vector<ConnectedFrame> agreeing;
    int loops_used = 0;  // of those, loops (both ends in one submap)
    // Maps the fixes place but GNSS does not join, by root, and why (GnssJoining::not_joined).
    std::map<SubmapId, std::string> not_joined_by_gnss;
    // Each merged map the fixes place on Earth, by component (MapsOnEarth).
    std::map<int, MergedMapOnEarth> on_earth;
  };
  // `gnss`: each submap's fixes, in one ENU frame, to join the merged maps that views leave apart
  // (JoinByGnss); its junctions are then in `edges` and `tree` (EdgeKind::kGnss).
  Graph Solve(bool refine = false, const SubmapFixes& gnss = {}) const;

  // Verifies again, with the submaps' points as they are now, every connected frame and loop
  // verified on an older revision of either submap. A connection is verified once, when its
  // keyframe arrives: the points of a young submap move a lot under its mapper's bundle
  // adjustment afterwards, and behind a busy link the mapper holds their refinements back, so
  // early points can agree on a similarity tens of degrees off (docs/merger.md). One that
  // cannot be verified again (a keyframe culled, too few matches now) is kept as stale
  // (ConnectedFrame::stale). The service calls it before each refinement.
  struct Reverification {
    int reverified = 0;
    int changed = 0;  // the similarity moved beyond SimilaritiesAgree
    int stale = 0;    // not verified again: kept as it was, marked stale
  };
  Reverification ReverifyStaleConnections();

  // The check after placement (CheckJunctions) doubted `edge`'s merge: Solve refuses the edge,
  // with `reason`, until its pair has more agreeing connected frames than now.
  void RefuseAfterPlacement(const SubmapEdge& edge, const std::string& reason);

  const std::map<SubmapId, SubmapReplica>& submaps() const { return submaps_; }
  const std::vector<ConnectedFrame>& connections() const { return connections_; }
  const std::vector<ConnectedFrame>& loops() const { return loops_; }  // both ends in one submap
  // Verified, but refused by RefuseConnection (ConnectedFrame::refused says why); never used.
  const std::vector<ConnectedFrame>& refused() const { return refused_; }
  const std::vector<RetrievalRecord>& retrievals() const { return retrievals_; }
  const MergerOptions& options() const { return options_; }

 private:
  // Files a verified connection (or loop) where it belongs: `accepted` or, with its reason,
  // refused_. Returns whether it was accepted.
  bool File(ConnectedFrame connection, std::vector<ConnectedFrame>* accepted);
  void Prepare(SubmapReplica* replica, Keyframe* keyframe);
  RetrievalRecord Retrieve(const SubmapReplica& replica, const Keyframe& keyframe);
  void RetrieveLoops(const SubmapReplica& replica, const Keyframe& keyframe, RetrievalRecord* record);
  // `matches` / `inliers` (optional) receive the counts whatever the outcome.
  std::optional<ConnectedFrame> Verify(const SubmapReplica& a, const Keyframe& keyframe_a, const SubmapReplica& b,
                                       const Keyframe& keyframe_b, int* matches, int* inliers) const;
  // `matched_a` / `matched_b`: the features of each keyframe matched already (more are marked).
  std::optional<Sim3Estimate> VerifyByProjection(const SubmapReplica& a, const Keyframe& keyframe_a,
                                                 const SubmapReplica& b, const Keyframe& keyframe_b,
                                                 std::vector<char>* matched_a, std::vector<char>* matched_b,
                                                 std::vector<Sim3Correspondence>* pairs,
                                                 std::vector<std::pair<MapPointId, MapPointId>>* point_ids,
                                                 int* inlier_count) const;
  // Keyframe a relocalized among b's points of `pairs` (their pixels in a); the similarity from
  // its two poses and the points' distances.
  std::optional<Sim3Estimate> VerifyByRelocalization(const Keyframe& keyframe_a, const PinholeIntrinsics& k,
                                                     const std::vector<Sim3Correspondence>& pairs,
                                                     int* inlier_count) const;
  const Undistorter& UndistorterFor(const Camera& camera);
  std::map<KeyframeId, Sim3d> RefineKeyframePoses(const std::map<SubmapId, SubmapPlacement>& placement,
                                                  Graph* graph) const;
  // Loops confirmed by another loop between the same places with the same correction.
  std::vector<ConnectedFrame> ConfirmedLoops() const;

  MergerOptions options_;
  const Vocabulary* vocabulary_;
  ScalePyramid pyramid_;
  std::map<SubmapId, SubmapReplica> submaps_;
  std::map<std::string, Undistorter> undistorters_;  // by camera description
  KeyframeDatabase database_;
  std::set<KeyframeId> prepared_;  // keyframes with undistorted points and BoW
  std::vector<ConnectedFrame> connections_;
  std::vector<ConnectedFrame> loops_;
  std::vector<ConnectedFrame> refused_;
  std::vector<RetrievalRecord> retrievals_;
  struct PlacementRefusal {
    int connected_frames = 0;  // the edge's when refused
    std::string reason;
  };
  std::map<std::pair<SubmapId, SubmapId>, PlacementRefusal> refused_after_placement_;  // smaller id first
};

}  // namespace stitch
