#pragma once
// The merger's submap graph (docs/method.md, steps 3-4): verified connected frames between submaps
// give each pair of submaps a connection strength C = F + 0.1 M + 0.1 theta_m^2 (weights in
// MergerOptions::connection_weights); pairs at or
// above a threshold are edges of weight -C, and Kruskal's minimum spanning tree over them (the
// strongest connections) decides which submaps merge, and in which order. Each merged map is
// then expressed in the frame of its largest submap by composing the edges' Sim3 along the tree.

#include <cmath>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "stitch/geometry/rigid3.h"
#include "stitch/merging/merger_options.h"
#include "stitch/util/ids.h"

namespace stitch {

// How a connected frame was verified (Merger::Verify) and how well its agreeing points pin the
// similarity: a connection can pass verification with points that leave a rotation free.
enum class VerifiedBy { kDescriptors, kProjection, kRelocalization };
const char* VerifiedByName(VerifiedBy how);
struct ConnectionGeometry {
  VerifiedBy verified_by = VerifiedBy::kDescriptors;
  // Spread of the agreeing points' bearings in each keyframe: the smaller principal standard
  // deviation of their normalized image coordinates (about radians). Points in one corner or
  // along one image line give a small value.
  double bearing_spread_a = 0, bearing_spread_b = 0;
  // Shape of the points in 3D (a's frame): the middle principal standard deviation over the
  // largest, over the 80% nearest their median. Near 0: the points lie close to a line.
  double line_ratio = 0;
  // Median distance between a's points carried into b's frame and b's own points, over their
  // distance from b's camera: 0 when the two submaps agree on where the points are, not only on
  // the directions they are seen in.
  double depth_disagreement = 0;
};

// Why a verified connection cannot place a submap ("" when it can): its points lie near a line,
// or are seen along nearly parallel rays in either keyframe (AcceptanceOptions).
std::string RefuseConnection(const ConnectionGeometry& geometry, const AcceptanceOptions& options);

// A keyframe of submap `a` verified against a keyframe of submap `b`.
struct ConnectedFrame {
  KeyframeId keyframe_a, keyframe_b;
  Sim3d b_from_a;               // submap b's frame from submap a's
  int map_points = 0;           // matched map points that agree with b_from_a
  double median_angle_deg = 0;  // median intersection angle of those points' rays from the two cameras
  std::vector<std::pair<MapPointId, MapPointId>> point_pairs;  // those points: (in a, in b)
  ConnectionGeometry geometry;                                 // how well those points pin the Sim3
  int revision_a = -1, revision_b = -1;                        // the submaps' revisions it was verified on
  std::string refused;                                         // RefuseConnection's reason; "" when accepted
  // Verified on older points of its submaps and not verified again on the current ones (a
  // keyframe culled, or too few matches now): SummarizeConnections counts it only where the
  // pair's current connected frames agree with it, or where the pair has no other.
  bool stale = false;
};

// Two measurements of one Sim3 agree when they differ by at most this much rotation and log
// scale. On the default gust flight correct connected frames of a pair differ by at most 3
// degrees and 0.016 (docs/merger.md); a wrong one (points close to a line, whose rotation about
// it nothing constrains) by tens of degrees.
constexpr double kAgreeingRotationRad = 5.0 * M_PI / 180.0;
constexpr double kAgreeingLogScale = 0.05;
bool SimilaritiesAgree(const Sim3d& x, const Sim3d& y);

// C = frames * F + points * M + angle * theta^2, theta capped at 45 degrees (the method's weights
// by default: F + 0.1 M + 0.1 theta^2).
double ConnectionStrength(int connected_frames, int map_points, double median_angle_deg,
                          const ConnectionWeights& weights = ConnectionWeights());

// A pair of submaps as a key, the smaller id first.
inline std::pair<SubmapId, SubmapId> SubmapPair(SubmapId a, SubmapId b) {
  return a < b ? std::make_pair(a, b) : std::make_pair(b, a);
}

// What joins an edge's two submaps: verified connected frames (shared views), or their maps'
// placements by the aircraft's GNSS where no view connects them (gnss_junctions.h).
enum class EdgeKind { kVisual, kGnss };

struct SubmapEdge {
  SubmapId a, b;
  EdgeKind kind = EdgeKind::kVisual;
  double gnss_sigma_m = 0;      // kGnss: the two placements' standard error at the junction, metres
  int connected_frames = 0;     // F
  int map_points = 0;           // M
  double median_angle_deg = 0;  // theta_m, over the connected frames
  double strength = 0;          // C
  Sim3d b_from_a;               // from the connected frame with the most map points among the agreeing ones
  int disagreeing_frames = 0;   // connected frames left out because they disagree with b_from_a
  double agreement = 0;         // share of the pair's voting map points whose rotation agrees with b_from_a
  std::string refused;          // why it may not merge its submaps (CheckEdges, CheckCycles); "" when it may
};

// One edge per pair of submaps with connected frames between them (either direction). The
// pair's connected frames vote: the Sim3 that the most map points agree with (SimilaritiesAgree,
// summed over the connected frames that agree with it) wins, and F, M and theta_m count only
// the connected frames that agree with it, so one wrong connected frame with many points can
// neither place a submap nor strengthen its edge. Stale connected frames vote only when the
// pair has no other. `agreement` is the share of the voting points whose rotation agrees.
std::vector<SubmapEdge> SummarizeConnections(const std::vector<ConnectedFrame>& connections,
                                             const ConnectionWeights& weights = ConnectionWeights());

struct SubmapPlacement {
  int component = -1;  // merged map; 0 is the one with the most keyframes
  SubmapId root;       // the component's largest submap, whose frame is the component's
  Sim3d world_from_submap;
  // The root of the submaps that views join (the whole component, unless a GNSS junction joins
  // parts): its first keyframe holds that part in the adjustments, where nothing else connects
  // it. Invalid: the root.
  SubmapId anchor;
  SubmapId Anchor() const { return anchor.valid() ? anchor : root; }
};

// Refuses (SubmapEdge::refused) the edges strong enough to merge (C >= `min_strength`) that one
// place or a split vote would decide: fewer
// than `min_connected_frames` agreeing connected frames, or less than `min_agreement` of the
// pair's points agreeing with the winning Sim3 (its connected frames point two ways: wait for
// more evidence, e.g. the submaps' refined points).
void CheckEdges(std::vector<SubmapEdge>* edges, double min_strength, const AcceptanceOptions& options);

// Keyframes a submap's manifest lists, and how many of them its copy lacks.
struct SubmapCompleteness {
  int listed = 0;
  int missing = 0;
};

// Refuses the edges strong enough to merge whose either submap lacks more than
// `max_missing` of its listed keyframes: the link has not brought them, and what the copy holds
// may be a young submap's early points, or a long submap's first keyframes only. The edge waits
// for them (a later refinement looks again).
void CheckCompleteness(std::vector<SubmapEdge>* edges, double min_strength,
                       const std::map<SubmapId, SubmapCompleteness>& completeness, double max_missing);

// Edges outside the tree whose two submaps the tree placed in one merged map must agree with
// that placement (the Sim3s around the cycle they close compose to the identity); one that
// does not is refused with how far off it is. The tree's own edges are stronger, so the
// closing edge is the one doubted.
void CheckCycles(std::vector<SubmapEdge>* edges, const std::vector<SubmapEdge>& tree,
                 const std::map<SubmapId, SubmapPlacement>& placement);

// Whether `tree` holds the edge between `edge`'s two submaps, of the same kind.
bool InTree(const SubmapEdge& edge, const std::vector<SubmapEdge>& tree);

// What became of an edge: "merged" (a tree edge), "joined by GNSS (+-S m)" (a GNSS junction),
// "agrees" (closes a cycle consistently), "below min_connection_strength", or "refused: <reason>".
std::string EdgeStatus(const SubmapEdge& edge, const std::vector<SubmapEdge>& tree, double min_strength);

// What became of a connected frame: "refused: <reason>" (RefuseConnection), "loop" (both ends
// in one submap), "outvoted" (disagrees with its pair's Sim3), or its edge's EdgeStatus.
std::string ConnectionVerdict(const ConnectedFrame& connection, const std::vector<SubmapEdge>& edges,
                              const std::vector<SubmapEdge>& tree, double min_strength);

// Kruskal on weights -strength over the edges with strength >= `min_strength` and not refused:
// the tree edges in the order they are taken (strongest first; ties by the smaller submap ids).
std::vector<SubmapEdge> MinimumSpanningForest(const std::vector<SubmapId>& submaps, std::vector<SubmapEdge> edges,
                                              double min_strength);

// Components of the forest and each submap's Sim3 in its component (composed along the tree
// from the root; the anchor is the root). `keyframes` gives each submap's size.
std::map<SubmapId, SubmapPlacement> PlaceSubmaps(const std::map<SubmapId, int>& keyframes,
                                                 const std::vector<SubmapEdge>& tree);

}  // namespace stitch
