#include "stitch/merging/pose_graph.h"

#include <random>

#include <gtest/gtest.h>

namespace stitch {
namespace {

// Keyframes along a path, world_from_cam with a slowly drifting scale.
std::map<KeyframeId, Sim3d> Path(int n) {
  std::map<KeyframeId, Sim3d> poses;
  for (int k = 0; k < n; ++k) {
    poses[MakeKeyframeId(MakeSubmapId(0, 1), k)] = Sim3d(
        1.0 + 0.01 * k, Eigen::Quaterniond(Eigen::AngleAxisd(0.05 * k, Eigen::Vector3d(0.1, 0.2, 1).normalized())),
        Eigen::Vector3d(0.5 * k, 0.1 * k * k / n, 0.02 * k));
  }
  return poses;
}

std::vector<PoseGraphEdge> ExactEdges(const std::map<KeyframeId, Sim3d>& poses) {
  std::vector<PoseGraphEdge> edges;
  KeyframeId previous;
  for (const auto& [id, pose] : poses) {
    if (previous.valid()) edges.push_back({previous, id, poses.at(previous).Inverse() * pose});
    previous = id;
  }
  // A loop: the last keyframe measured from the first.
  edges.push_back({poses.begin()->first, poses.rbegin()->first,
                   poses.begin()->second.Inverse() * poses.rbegin()->second, 1.0, true});
  return edges;
}

double MaxCentreError(const std::map<KeyframeId, Sim3d>& a, const std::map<KeyframeId, Sim3d>& b) {
  double worst = 0;
  for (const auto& [id, pose] : a) worst = std::max(worst, (pose.translation - b.at(id).translation).norm());
  return worst;
}

TEST(PoseGraph, AConsistentGraphStaysWhereItIs) {
  const auto truth = Path(20);
  auto poses = truth;
  const auto report = OptimizePoseGraph(&poses, ExactEdges(truth), {truth.begin()->first});
  EXPECT_EQ(report.nodes, 20);
  EXPECT_LT(MaxCentreError(poses, truth), 1e-6);
}

TEST(PoseGraph, PerturbedKeyframesReturnToTheirMeasuredPlaces) {
  const auto truth = Path(20);
  auto poses = truth;
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0, 0.05);
  for (auto& [id, pose] : poses) {
    if (id == truth.begin()->first) continue;
    pose.translation += Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
    pose.rotation =
        (pose.rotation * Eigen::Quaterniond(Eigen::AngleAxisd(noise(rng), Eigen::Vector3d::UnitX()))).normalized();
    pose.scale *= std::exp(noise(rng));
  }
  OptimizePoseGraph(&poses, ExactEdges(truth), {truth.begin()->first}, 50);
  EXPECT_LT(MaxCentreError(poses, truth), 1e-3);
}

}  // namespace
}  // namespace stitch
