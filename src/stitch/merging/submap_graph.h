#pragma once
// The merger's submap graph (docs/method.md, steps 3-4): verified connected frames between submaps
// give each pair of submaps a connection strength C = F + 0.1 M + 0.1 theta_m^2 (weights in
// MergerOptions::connection_weights); pairs at or
// above a threshold are edges of weight -C, and Kruskal's minimum spanning tree over them (the
// strongest connections) decides which submaps merge, and in which order. Each merged map is
// then expressed in the frame of its largest submap by composing the edges' Sim3 along the tree.

#include <cmath>
#include <map>
#include <utility>
#include <vector>

#include "stitch/geometry/rigid3.h"
#include "stitch/merging/merger_options.h"
#include "stitch/util/ids.h"

namespace stitch {

// A keyframe of submap `a` verified against a keyframe of submap `b`.
struct ConnectedFrame {
  KeyframeId keyframe_a, keyframe_b;
  Sim3d b_from_a;               // submap b's frame from submap a's
  int map_points = 0;           // matched map points that agree with b_from_a
  double median_angle_deg = 0;  // median intersection angle of those points' rays from the two cameras
  std::vector<std::pair<MapPointId, MapPointId>> point_pairs;  // those points: (in a, in b)
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

struct SubmapEdge {
  SubmapId a, b;
  int connected_frames = 0;     // F
  int map_points = 0;           // M
  double median_angle_deg = 0;  // theta_m, over the connected frames
  double strength = 0;          // C
  Sim3d b_from_a;               // from the connected frame with the most map points among the agreeing ones
  int disagreeing_frames = 0;   // connected frames left out because they disagree with b_from_a
};

// One edge per pair of submaps with connected frames between them (either direction). The
// pair's connected frames vote: the Sim3 that the most map points agree with (SimilaritiesAgree,
// summed over the connected frames that agree with it) wins, and F, M and theta_m count only
// the connected frames that agree with it, so one wrong connected frame with many points can
// neither place a submap nor strengthen its edge.
std::vector<SubmapEdge> SummarizeConnections(const std::vector<ConnectedFrame>& connections,
                                             const ConnectionWeights& weights = ConnectionWeights());

// Kruskal on weights -strength over the edges with strength >= `min_strength`: the tree edges
// in the order they are taken (strongest first; ties by the smaller submap ids).
std::vector<SubmapEdge> MinimumSpanningForest(const std::vector<SubmapId>& submaps, std::vector<SubmapEdge> edges,
                                              double min_strength);

struct SubmapPlacement {
  int component = -1;  // merged map; 0 is the one with the most keyframes
  SubmapId root;       // the component's largest submap, whose frame is the component's
  Sim3d world_from_submap;
};

// Components of the forest and each submap's Sim3 in its component (composed along the tree
// from the root). `keyframes` gives each submap's size.
std::map<SubmapId, SubmapPlacement> PlaceSubmaps(const std::map<SubmapId, int>& keyframes,
                                                 const std::vector<SubmapEdge>& tree);

}  // namespace stitch
