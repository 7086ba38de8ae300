#include "stitch/merging/submap_graph.h"

#include <algorithm>
#include <cmath>
#include <deque>
#include <numeric>

namespace stitch {
namespace {

double Median(std::vector<double> values) {
  if (values.empty()) return 0;
  const size_t middle = values.size() / 2;
  std::nth_element(values.begin(), values.begin() + middle, values.end());
  return values[middle];
}

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

}  // namespace

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
  };
  std::map<std::pair<SubmapId, SubmapId>, std::vector<Measurement>> pairs;
  for (const ConnectedFrame& c : connections) {
    SubmapId a = SubmapOf(c.keyframe_a), b = SubmapOf(c.keyframe_b);
    Sim3d b_from_a = c.b_from_a;
    if (b < a) {
      std::swap(a, b);
      b_from_a = b_from_a.Inverse();
    }
    pairs[{a, b}].push_back({b_from_a, c.map_points, c.median_angle_deg});
  }
  std::vector<SubmapEdge> edges;
  for (const auto& [key, measurements] : pairs) {
    // The measurement the most map points agree with; among equals, the one with the most
    // points of its own, then the first found.
    size_t best = 0;
    int best_support = -1;
    for (size_t i = 0; i < measurements.size(); ++i) {
      int support = 0;
      for (const Measurement& other : measurements) {
        if (SimilaritiesAgree(measurements[i].b_from_a, other.b_from_a)) support += other.map_points;
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
    for (const Measurement& m : measurements) {
      if (!SimilaritiesAgree(edge.b_from_a, m.b_from_a)) {
        ++edge.disagreeing_frames;
        continue;
      }
      ++edge.connected_frames;
      edge.map_points += m.map_points;
      angles.push_back(m.median_angle_deg);
    }
    edge.median_angle_deg = Median(angles);
    edge.strength = ConnectionStrength(edge.connected_frames, edge.map_points, edge.median_angle_deg, weights);
    edges.push_back(edge);
  }
  return edges;
}

std::vector<SubmapEdge> MinimumSpanningForest(const std::vector<SubmapId>& submaps, std::vector<SubmapEdge> edges,
                                              double min_strength) {
  std::map<SubmapId, size_t> index;
  for (SubmapId id : submaps) index.emplace(id, index.size());
  edges.erase(std::remove_if(edges.begin(), edges.end(),
                             [&](const SubmapEdge& e) {
                               return e.strength < min_strength || !index.count(e.a) || !index.count(e.b) || e.a == e.b;
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
    placement[c.root] = {static_cast<int>(ci), c.root, Sim3d()};
    std::map<SubmapId, bool> done{{c.root, true}};
    while (!queue.empty()) {
      const SubmapId s = queue.front();
      queue.pop_front();
      for (const auto& [other, other_from_this] : neighbours[s]) {
        if (done[other]) continue;
        done[other] = true;
        placement[other] = {static_cast<int>(ci), c.root, placement[s].world_from_submap * other_from_this.Inverse()};
        queue.push_back(other);
      }
    }
  }
  return placement;
}

}  // namespace stitch
