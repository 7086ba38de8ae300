#include "stitch/map/map_export.h"

#include <random>
#include <string>

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

// Two aircraft with different cameras in one map: each keyframe's image takes its own camera, one
// model camera per calibration; a keyframe without a camera is left out, and its observations.
TEST(MapExport, AMapOfTwoCamerasGivesEachImageItsOwn) {
  const Camera first = Camera::Pinhole(640, 480, 450, 450, 319.5, 239.5);
  const Camera second = Camera::Pinhole(752, 480, 458, 457, 367, 248, -0.28, 0.07);
  const SubmapId submap_a = MakeSubmapId(0, 1), submap_b = MakeSubmapId(1, 1);
  Map map(submap_a, ScalePyramid::From(OrbOptions()));
  const std::vector<Eigen::Vector3d> points = {{0, 0, 5}, {1, -0.5, 6}, {-1, 0.7, 4}};
  const std::vector<KeyframeId> ids = {MakeKeyframeId(submap_a, 0), MakeKeyframeId(submap_b, 0),
                                       MakeKeyframeId(submap_a, 1), MakeKeyframeId(MakeSubmapId(2, 1), 0)};
  for (size_t k = 0; k < ids.size(); ++k) {
    Keyframe keyframe;
    keyframe.id = ids[k];
    keyframe.frame_index = static_cast<int>(k);
    keyframe.cam_from_world = Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(-0.3 * k, 0, 0));
    const Camera& camera = SubmapOf(ids[k]) == submap_b ? second : first;
    for (const Eigen::Vector3d& p : points) {
      const Eigen::Vector2d pixel = *camera.Project(keyframe.cam_from_world * p);
      keyframe.keypoints.emplace_back(static_cast<float>(pixel.x()), static_cast<float>(pixel.y()), 31.f);
    }
    keyframe.points.assign(points.size(), MapPointId());
    map.AddKeyframe(std::move(keyframe));
  }
  for (size_t p = 0; p < points.size(); ++p) {
    MapPoint point;
    point.id = map.NewPointId();
    point.position = points[p];
    const MapPointId id = map.AddPoint(point).id;
    for (const KeyframeId& keyframe : ids) map.AddObservation(keyframe, static_cast<int>(p), id);
  }
  const auto camera_of = [&](const Keyframe& keyframe) -> const Camera* {
    if (SubmapOf(keyframe.id) == submap_a) return &first;
    if (SubmapOf(keyframe.id) == submap_b) return &second;
    return nullptr;  // an aircraft whose camera the ground never heard of
  };
  MapExportOptions options;
  options.min_observations = 2;
  const ColmapModel model =
      ColmapModelOf(map, camera_of, options, [](const Keyframe& k) { return std::to_string(k.frame_index) + ".png"; });
  ASSERT_EQ(model.cameras.size(), 2u);
  EXPECT_EQ(model.cameras.at(1).Describe(), first.Describe());
  EXPECT_EQ(model.cameras.at(2).Describe(), second.Describe());
  ASSERT_EQ(model.images.size(), 3u);
  EXPECT_EQ(model.images[0].camera_id, 1);
  EXPECT_EQ(model.images[1].camera_id, 2);
  EXPECT_EQ(model.images[2].camera_id, 1);
  ASSERT_EQ(model.points.size(), 3u);
  EXPECT_EQ(model.points[0].track.size(), 3u);
  EXPECT_LT(ReprojectionRms(model), 1e-3);
}

}  // namespace
}  // namespace stitch
