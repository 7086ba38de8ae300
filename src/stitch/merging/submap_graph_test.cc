#include "stitch/merging/submap_graph.h"

#include <gtest/gtest.h>

namespace stitch {
namespace {

SubmapId S(char name) {
  return MakeSubmapId(0, name - 'A' + 1);
}

SubmapEdge Edge(char a, char b, double strength, const Sim3d& b_from_a = Sim3d()) {
  SubmapEdge e;
  e.a = S(a);
  e.b = S(b);
  e.strength = strength;
  e.b_from_a = b_from_a;
  return e;
}

ConnectedFrame Connection(KeyframeId a, KeyframeId b, const Sim3d& b_from_a, int map_points, double angle_deg) {
  ConnectedFrame c;
  c.keyframe_a = a;
  c.keyframe_b = b;
  c.b_from_a = b_from_a;
  c.map_points = map_points;
  c.median_angle_deg = angle_deg;
  return c;
}

std::vector<std::string> Names(const std::vector<SubmapEdge>& tree) {
  std::vector<std::string> names;
  for (const auto& e : tree) {
    names.push_back(std::string(1, static_cast<char>('A' + SubmapNumber(e.a) - 1)) + "-" +
                    std::string(1, static_cast<char>('A' + SubmapNumber(e.b) - 1)));
  }
  return names;
}

TEST(SubmapGraph, ConnectionStrengthFollowsTheFormulaAndCapsTheAngle) {
  EXPECT_DOUBLE_EQ(ConnectionStrength(3, 100, 20), 3 + 10 + 40);
  EXPECT_DOUBLE_EQ(ConnectionStrength(1, 0, 60), 1 + 0.1 * 45 * 45);
  EXPECT_DOUBLE_EQ(ConnectionStrength(0, 0, 0), 0);
}

TEST(SubmapGraph, ConnectionsOfAPairInEitherDirectionMakeOneEdge) {
  const Sim3d b_from_a(2.0, Eigen::Quaterniond::Identity(), Eigen::Vector3d(1, 0, 0));
  std::vector<ConnectedFrame> connections = {
      Connection(MakeKeyframeId(S('A'), 5), MakeKeyframeId(S('B'), 7), b_from_a, 40, 10.0),
      Connection(MakeKeyframeId(S('B'), 8), MakeKeyframeId(S('A'), 6), b_from_a.Inverse(), 60, 20.0),
      Connection(MakeKeyframeId(S('B'), 9), MakeKeyframeId(S('A'), 7), b_from_a.Inverse(), 30, 30.0),
  };
  const auto edges = SummarizeConnections(connections);
  ASSERT_EQ(edges.size(), 1u);
  EXPECT_EQ(edges[0].a, S('A'));
  EXPECT_EQ(edges[0].connected_frames, 3);
  EXPECT_EQ(edges[0].map_points, 130);
  EXPECT_DOUBLE_EQ(edges[0].median_angle_deg, 20.0);
  EXPECT_DOUBLE_EQ(edges[0].strength, 3 + 13 + 40);
  EXPECT_NEAR(edges[0].b_from_a.scale, 2.0, 1e-12);  // expressed as B from A whichever way it was found
}

// Points close to a line leave the Sim3's rotation about that line free: such a connected frame
// can pass verification with many points and still be tens of degrees off. The pair's other
// connected frames outvote it, and it neither places the submap nor counts in the strength.
TEST(SubmapGraph, ConnectedFramesThatDisagreeWithTheOthersAreOutvoted) {
  const Sim3d b_from_a(0.77, Eigen::Quaterniond(Eigen::AngleAxisd(0.87, Eigen::Vector3d::UnitZ())),
                       Eigen::Vector3d(-0.3, -0.6, 0.2));
  const auto nudged = [&](double degrees) {
    Sim3d s = b_from_a;
    s.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(degrees * M_PI / 180.0, Eigen::Vector3d::UnitX())) * s.rotation;
    return s;
  };
  const Sim3d wrong = nudged(35.0);
  std::vector<ConnectedFrame> connections = {
      Connection(MakeKeyframeId(S('B'), 4), MakeKeyframeId(S('A'), 1), b_from_a, 25, 43.0),
      Connection(MakeKeyframeId(S('B'), 3), MakeKeyframeId(S('A'), 1), wrong, 40, 4.7),  // the most points
      Connection(MakeKeyframeId(S('B'), 6), MakeKeyframeId(S('A'), 1), nudged(1.0), 27, 45.0),
      Connection(MakeKeyframeId(S('B'), 5), MakeKeyframeId(S('A'), 9), nudged(-2.0), 23, 28.0),
  };
  // Found from B's keyframes: each measures A's frame from B's; the edge is B from A.
  for (auto& c : connections) c.b_from_a = c.b_from_a.Inverse();
  auto edges = SummarizeConnections(connections);
  ASSERT_EQ(edges.size(), 1u);
  const SubmapEdge& edge = edges[0];
  EXPECT_EQ(edge.a, S('A'));
  EXPECT_TRUE(SimilaritiesAgree(edge.b_from_a, b_from_a));
  EXPECT_FALSE(SimilaritiesAgree(edge.b_from_a, wrong));
  EXPECT_EQ(edge.connected_frames, 3);
  EXPECT_EQ(edge.disagreeing_frames, 1);
  EXPECT_EQ(edge.map_points, 25 + 27 + 23);
  EXPECT_DOUBLE_EQ(edge.median_angle_deg, 43.0);
  // The agreeing one with the most points of its own gives the Sim3 (27 points, 1 degree off).
  EXPECT_NEAR(RotationAngle(edge.b_from_a.rotation * nudged(1.0).rotation.inverse()), 0.0, 1e-9);

  // Alone, the wrong one is all there is: it still makes the edge (nothing can outvote it).
  edges = SummarizeConnections({connections[1]});
  ASSERT_EQ(edges.size(), 1u);
  EXPECT_EQ(edges[0].connected_frames, 1);
  EXPECT_EQ(edges[0].disagreeing_frames, 0);
}

// Our example of nine submaps: a cycle, ties, an edge under the threshold and two components.
TEST(SubmapGraph, KruskalTakesTheStrongestConnectionsInOrder) {
  std::vector<SubmapId> nodes;
  for (char c = 'A'; c <= 'I'; ++c) nodes.push_back(S(c));
  const std::vector<SubmapEdge> edges = {Edge('A', 'B', 50), Edge('B', 'C', 40), Edge('A', 'C', 45),
                                         Edge('D', 'E', 30), Edge('C', 'D', 30), Edge('E', 'F', 5),
                                         Edge('H', 'I', 20), Edge('G', 'H', 20), Edge('G', 'I', 60)};
  const auto tree = MinimumSpanningForest(nodes, edges, 10.0);
  EXPECT_EQ(Names(tree), (std::vector<std::string>{"G-I", "A-B", "A-C", "C-D", "D-E", "G-H"}));
  // F is left alone (its only edge is too weak): three merged maps, the largest first.
  std::map<SubmapId, int> keyframes;
  for (char c = 'A'; c <= 'I'; ++c) keyframes[S(c)] = 10;
  keyframes[S('B')] = 30;
  const auto placement = PlaceSubmaps(keyframes, tree);
  EXPECT_EQ(placement.at(S('A')).component, 0);
  EXPECT_EQ(placement.at(S('E')).component, 0);
  EXPECT_EQ(placement.at(S('B')).root, S('B'));
  EXPECT_EQ(placement.at(S('G')).component, 1);
  EXPECT_EQ(placement.at(S('I')).component, 1);
  EXPECT_EQ(placement.at(S('F')).component, 2);
  EXPECT_TRUE(MinimumSpanningForest(nodes, {}, 10.0).empty());
}

TEST(SubmapGraph, PlacementComposesTheSimilaritiesAlongTheTree) {
  const Sim3d b_from_a(2.0, Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ())),
                       Eigen::Vector3d(1, 2, 3));
  const Sim3d c_from_b(0.5, Eigen::Quaterniond(Eigen::AngleAxisd(-0.2, Eigen::Vector3d::UnitX())),
                       Eigen::Vector3d(0, 1, 0));
  const std::vector<SubmapEdge> tree = {Edge('A', 'B', 50, b_from_a), Edge('B', 'C', 40, c_from_b)};
  const auto placement = PlaceSubmaps({{S('A'), 20}, {S('B'), 5}, {S('C'), 5}}, tree);
  // A point of the world (A's frame) seen in C's frame comes back to the same place.
  const Eigen::Vector3d in_a(0.3, -1.0, 4.0);
  const Eigen::Vector3d in_c = c_from_b * (b_from_a * in_a);
  EXPECT_LT((placement.at(S('C')).world_from_submap * in_c - in_a).norm(), 1e-9);
  EXPECT_LT((placement.at(S('A')).world_from_submap * in_a - in_a).norm(), 1e-12);
}

}  // namespace
}  // namespace stitch
