#include "stitch/merging/submap_graph.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <deque>
#include <numeric>

#include "stitch/util/statistics.h"

namespace stitch {
namespace {

// Union-find over submap indices.
class DisjointSets {
 public:
  explicit DisjointSets(size_t n) : parent_(n) { std::iota(parent_.begin(), parent_.end(), 0); }
  size_t Find(size_t i) {
    while (parent_[i] != i) i = parent_[i] = parent_[parent_[i]];
    return i;
  }
  bool Join(size_t a, size_t b) {
    a = Find(a);
    b = Find(b);
    if (a == b) return false;
    parent_[std::max(a, b)] = std::min(a, b);
    return true;
  }

 private:
  std::vector<size_t> parent_;
};

// A connected frame's two submaps in id order, and its Sim3 as the second's frame from the first's.
struct OrientedPair {
  SubmapId a, b;
  Sim3d b_from_a;
};
OrientedPair Orient(const ConnectedFrame& c) {
  OrientedPair pair{SubmapOf(c.keyframe_a), SubmapOf(c.keyframe_b), c.b_from_a};
  if (pair.b < pair.a) {
    std::swap(pair.a, pair.b);
    pair.b_from_a = pair.b_from_a.Inverse();
  }
  return pair;
}

}  // namespace

const char* VerifiedByName(VerifiedBy how) {
  switch (how) {
    case VerifiedBy::kDescriptors:
      return "descriptors";
    case VerifiedBy::kProjection:
      return "projection";
    case VerifiedBy::kRelocalization:
      return "relocalization";
  }
  return "?";
}

std::string RefuseConnection(const ConnectionGeometry& g, const AcceptanceOptions& options) {
  char why[160];
  if (g.line_ratio < options.min_line_ratio) {
    std::snprintf(why, sizeof(why), "points near a line (spread ratio %.3f < %.3f)", g.line_ratio,
                  options.min_line_ratio);
    return why;
  }
  const double spread = std::min(g.bearing_spread_a, g.bearing_spread_b);
  if (spread < options.min_bearing_spread) {
    std::snprintf(why, sizeof(why), "rays near parallel (bearing spread %.4f < %.4f rad)", spread,
                  options.min_bearing_spread);
    return why;
  }
  return "";
}

double ConnectionStrength(int connected_frames, int map_points, double median_angle_deg,
                          const ConnectionWeights& weights) {
  const double theta = std::min(std::max(median_angle_deg, 0.0), 45.0);
  return weights.frames * connected_frames + weights.points * map_points + weights.angle * theta * theta;
}

bool SimilaritiesAgree(const Sim3d& x, const Sim3d& y) {
  const Sim3d difference = x.Inverse() * y;
  return RotationAngle(difference.rotation) <= kAgreeingRotationRad &&
         std::abs(std::log(difference.scale)) <= kAgreeingLogScale;
}

std::vector<SubmapEdge> SummarizeConnections(const std::vector<ConnectedFrame>& connections,
                                             const ConnectionWeights& weights) {
  struct Measurement {
    Sim3d b_from_a;
    int map_points;
    double median_angle_deg;
    bool stale;
  };
  std::map<std::pair<SubmapId, SubmapId>, std::vector<Measurement>> pairs;
  for (const ConnectedFrame& c : connections) {
    const OrientedPair pair = Orient(c);
    pairs[{pair.a, pair.b}].push_back({pair.b_from_a, c.map_points, c.median_angle_deg, c.stale});
  }
  std::vector<SubmapEdge> edges;
  for (const auto& [key, measurements] : pairs) {
    // Connected frames verified on the submaps' current points decide when there are any; those
    // that could not be verified again (ConnectedFrame::stale) count only where they agree.
    bool any_fresh = false;
    for (const Measurement& m : measurements) any_fresh |= !m.stale;
    const auto votes = [&](const Measurement& m) { return !any_fresh || !m.stale; };
    // The measurement the most map points agree with; among equals, the one with the most
    // points of its own, then the first found.
    size_t best = 0;
    int best_support = -1;
    for (size_t i = 0; i < measurements.size(); ++i) {
      if (!votes(measurements[i])) continue;
      int support = 0;
      for (const Measurement& other : measurements) {
        if (votes(other) && SimilaritiesAgree(measurements[i].b_from_a, other.b_from_a)) support += other.map_points;
      }
      if (support > best_support ||
          (support == best_support && measurements[i].map_points > measurements[best].map_points)) {
        best = i;
        best_support = support;
      }
    }
    SubmapEdge edge;
    edge.a = key.first;
    edge.b = key.second;
    edge.b_from_a = measurements[best].b_from_a;
    std::vector<double> angles;
    int voting_points = 0, turned_points = 0;
    for (const Measurement& m : measurements) {
      const bool agrees = SimilaritiesAgree(edge.b_from_a, m.b_from_a);
      if (votes(m) || agrees) {
        voting_points += m.map_points;
        // Split votes are about the rotation: a camera that only rotates measures the scale
        // between submaps loosely, but it does not turn a submap over.
        if (RotationAngle((edge.b_from_a.Inverse() * m.b_from_a).rotation) > kAgreeingRotationRad) {
          turned_points += m.map_points;
        }
      }
      if (!agrees) {
        ++edge.disagreeing_frames;
        continue;
      }
      ++edge.connected_frames;
      edge.map_points += m.map_points;
      angles.push_back(m.median_angle_deg);
    }
    edge.median_angle_deg = Median(angles);
    edge.agreement = voting_points > 0 ? 1.0 - static_cast<double>(turned_points) / voting_points : 0;
    edge.strength = ConnectionStrength(edge.connected_frames, edge.map_points, edge.median_angle_deg, weights);
    edges.push_back(edge);
  }
  return edges;
}

void CheckEdges(std::vector<SubmapEdge>* edges, double min_strength, const AcceptanceOptions& options) {
  for (SubmapEdge& e : *edges) {
    if (e.strength < min_strength) continue;  // too weak to merge anyway
    char why[160];
    if (e.connected_frames < options.min_connected_frames) {
      std::snprintf(why, sizeof(why), "%d agreeing connected frame%s (needs %d)", e.connected_frames,
                    e.connected_frames == 1 ? "" : "s", options.min_connected_frames);
      e.refused = why;
    } else if (e.agreement < options.min_agreement) {
      std::snprintf(why, sizeof(why),
                    "its connected frames disagree: %.0f%% of the points agree in rotation (needs %.0f%%)",
                    100 * e.agreement, 100 * options.min_agreement);
      e.refused = why;
    }
  }
}

void CheckCompleteness(std::vector<SubmapEdge>* edges, double min_strength,
                       const std::map<SubmapId, SubmapCompleteness>& completeness, double max_missing) {
  for (SubmapEdge& e : *edges) {
    if (e.strength < min_strength || !e.refused.empty()) continue;
    for (SubmapId id : {e.a, e.b}) {
      const auto it = completeness.find(id);
      if (it == completeness.end() || it->second.listed == 0) continue;
      const SubmapCompleteness& c = it->second;
      if (c.missing <= max_missing * c.listed) continue;
      char why[160];
      std::snprintf(why, sizeof(why), "submap %s lacks %d of its %d keyframes (not yet brought by the link)",
                    SubmapName(id).c_str(), c.missing, c.listed);
      e.refused = why;
      break;
    }
  }
}

void CheckCycles(std::vector<SubmapEdge>* edges, const std::vector<SubmapEdge>& tree,
                 const std::map<SubmapId, SubmapPlacement>& placement) {
  for (SubmapEdge& e : *edges) {
    if (!e.refused.empty()) continue;
    const auto pa = placement.find(e.a), pb = placement.find(e.b);
    if (InTree(e, tree) || pa == placement.end() || pb == placement.end() ||
        pa->second.component != pb->second.component) {
      continue;
    }
    const Sim3d placed = pb->second.world_from_submap.Inverse() * pa->second.world_from_submap;  // b from a
    if (SimilaritiesAgree(placed, e.b_from_a)) continue;
    const Sim3d difference = placed.Inverse() * e.b_from_a;
    char why[160];
    std::snprintf(why, sizeof(why), "its cycle does not close (%.1f deg, log scale %.3f from the tree's placement)",
                  RotationAngle(difference.rotation) * 180.0 / M_PI, std::log(difference.scale));
    e.refused = why;
  }
}

bool InTree(const SubmapEdge& edge, const std::vector<SubmapEdge>& tree) {
  return std::any_of(tree.begin(), tree.end(),
                     [&](const SubmapEdge& t) { return t.a == edge.a && t.b == edge.b && t.kind == edge.kind; });
}

std::string EdgeStatus(const SubmapEdge& edge, const std::vector<SubmapEdge>& tree, double min_strength) {
  if (InTree(edge, tree)) {
    if (edge.kind == EdgeKind::kVisual) return "merged";
    char status[64];
    std::snprintf(status, sizeof(status), "joined by GNSS (+-%.2f m)", edge.gnss_sigma_m);
    return status;
  }
  if (!edge.refused.empty()) return "refused: " + edge.refused;
  if (edge.strength < min_strength) return "below min_connection_strength";
  return "agrees";  // its submaps were joined by stronger edges, and it closes their cycle
}

std::string ConnectionVerdict(const ConnectedFrame& c, const std::vector<SubmapEdge>& edges,
                              const std::vector<SubmapEdge>& tree, double min_strength) {
  if (!c.refused.empty()) return "refused: " + c.refused;
  const OrientedPair pair = Orient(c);
  if (pair.a == pair.b) return "loop";
  for (const SubmapEdge& e : edges) {
    if (e.a != pair.a || e.b != pair.b) continue;
    return SimilaritiesAgree(e.b_from_a, pair.b_from_a) ? EdgeStatus(e, tree, min_strength) : "outvoted";
  }
  return "no edge";
}

std::vector<SubmapEdge> MinimumSpanningForest(const std::vector<SubmapId>& submaps, std::vector<SubmapEdge> edges,
                                              double min_strength) {
  std::map<SubmapId, size_t> index;
  for (SubmapId id : submaps) index.emplace(id, index.size());
  edges.erase(std::remove_if(edges.begin(), edges.end(),
                             [&](const SubmapEdge& e) {
                               return e.strength < min_strength || !e.refused.empty() || !index.count(e.a) ||
                                      !index.count(e.b) || e.a == e.b;
                             }),
              edges.end());
  // Weight -C ascending = strength descending.
  std::sort(edges.begin(), edges.end(), [](const SubmapEdge& x, const SubmapEdge& y) {
    if (x.strength != y.strength) return x.strength > y.strength;
    if (x.a != y.a) return x.a < y.a;
    return x.b < y.b;
  });
  DisjointSets sets(index.size());
  std::vector<SubmapEdge> tree;
  for (const SubmapEdge& e : edges) {
    if (sets.Join(index[e.a], index[e.b])) tree.push_back(e);
  }
  return tree;
}

std::map<SubmapId, SubmapPlacement> PlaceSubmaps(const std::map<SubmapId, int>& keyframes,
                                                 const std::vector<SubmapEdge>& tree) {
  std::map<SubmapId, std::vector<std::pair<SubmapId, Sim3d>>> neighbours;  // (other, other_from_this)
  for (const SubmapEdge& e : tree) {
    neighbours[e.a].push_back({e.b, e.b_from_a});
    neighbours[e.b].push_back({e.a, e.b_from_a.Inverse()});
  }
  // Components by flooding from each unplaced submap; the root is the largest (then lowest id).
  std::map<SubmapId, SubmapPlacement> placement;
  struct Component {
    std::vector<SubmapId> members;
    int keyframes = 0;
    SubmapId root;
  };
  std::vector<Component> components;
  for (const auto& [id, count] : keyframes) {
    if (placement.count(id)) continue;
    Component c;
    std::deque<SubmapId> queue{id};
    placement[id].component = -2;  // visited
    while (!queue.empty()) {
      const SubmapId s = queue.front();
      queue.pop_front();
      c.members.push_back(s);
      const auto k = keyframes.find(s);
      const int size = k == keyframes.end() ? 0 : k->second;
      c.keyframes += size;
      if (!c.root.valid() || size > keyframes.at(c.root) || (size == keyframes.at(c.root) && s < c.root)) c.root = s;
      for (const auto& [other, transform] : neighbours[s]) {
        if (placement.count(other)) continue;
        placement[other].component = -2;
        queue.push_back(other);
      }
    }
    components.push_back(std::move(c));
  }
  std::stable_sort(components.begin(), components.end(),
                   [](const Component& x, const Component& y) { return x.keyframes > y.keyframes; });
  for (size_t ci = 0; ci < components.size(); ++ci) {
    const Component& c = components[ci];
    // Sim3 from the root outwards: world = root frame; world_from_other = world_from_this * this_from_other.
    std::deque<SubmapId> queue{c.root};
    placement[c.root] = {static_cast<int>(ci), c.root, Sim3d(), c.root};
    std::map<SubmapId, bool> done{{c.root, true}};
    while (!queue.empty()) {
      const SubmapId s = queue.front();
      queue.pop_front();
      for (const auto& [other, other_from_this] : neighbours[s]) {
        if (done[other]) continue;
        done[other] = true;
        placement[other] = {static_cast<int>(ci), c.root, placement[s].world_from_submap * other_from_this.Inverse(),
                            c.root};
        queue.push_back(other);
      }
    }
  }
  return placement;
}

}  // namespace stitch
