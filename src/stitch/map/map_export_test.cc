#include "stitch/map/map_export.h"

#include <random>

#include <gtest/gtest.h>

namespace stitch {
namespace {

// A survey's points (a 60 x 40 m ground, 2 m of relief) with a few far ones, as a sparse map
// triangulated from nearly parallel rays holds them.
TEST(MapExport, LeavesOutPointsFarBeyondTheSceneAndPointsSeenOnce) {
  std::mt19937 random(3);
  std::uniform_real_distribution<double> x(-30, 30), y(-20, 20), z(-1, 1);
  std::vector<Eigen::Vector3d> positions;
  std::vector<int> observations;
  for (int i = 0; i < 2000; ++i) {
    positions.emplace_back(x(random), y(random), z(random));
    observations.push_back(2 + i % 5);
  }
  const size_t far_begin = positions.size();
  for (double distance : {1e3, 5e3, 6e4, -2e4}) {  // 15 to 1700 times the extent
    positions.emplace_back(distance, 3, 40);
    observations.push_back(3);
  }
  const size_t seen_once = positions.size();
  positions.emplace_back(1, 1, 0);  // inside the scene, but one keyframe sees it
  observations.push_back(1);
  positions.emplace_back(std::nan(""), 0, 0);
  observations.push_back(4);
  const size_t edge = positions.size();
  positions.emplace_back(200, 0, 0);  // 6 times the extent: far, but no outlier by this rule
  observations.push_back(2);

  const std::vector<bool> keep = PointsToExport(positions, observations, MapExportOptions());
  ASSERT_EQ(keep.size(), positions.size());
  for (size_t i = 0; i < far_begin; ++i) EXPECT_TRUE(keep[i]) << i;
  for (size_t i = far_begin; i < seen_once; ++i) EXPECT_FALSE(keep[i]) << positions[i].transpose();
  EXPECT_FALSE(keep[seen_once]);
  EXPECT_FALSE(keep[seen_once + 1]) << "not finite";
  EXPECT_TRUE(keep[edge]);
  // Stricter settings leave out more; none seen often enough: nothing to export.
  MapExportOptions strict;
  strict.max_extent_ratio = 2;
  EXPECT_FALSE(PointsToExport(positions, observations, strict)[edge]);
  strict.min_observations = 10;
  const auto none = PointsToExport(positions, observations, strict);
  EXPECT_EQ(std::count(none.begin(), none.end(), true), 0);
  EXPECT_TRUE(PointsToExport({}, {}, MapExportOptions()).empty());
}

}  // namespace
}  // namespace stitch
