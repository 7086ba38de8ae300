#include "stitch/merging/frame_trajectory.h"

#include <gtest/gtest.h>

#include "stitch/util/ids.h"

namespace stitch {
namespace {

const SubmapId kSubmap = MakeSubmapId(0, 1);
const KeyframeId kKeyframe = MakeKeyframeId(kSubmap, 3);

Rigid3d Turn(double angle, const Eigen::Vector3d& t) {
  return Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(angle, Eigen::Vector3d(0.2, 1, 0.1).normalized())), t);
}

Rigid3d Placed(const Sim3d& world_from_submap, const Rigid3d& submap_from_cam) {
  const Sim3d pose = world_from_submap * Sim3d(1.0, submap_from_cam.rotation, submap_from_cam.translation);
  return Rigid3d(pose.rotation, pose.translation);
}

void ExpectSamePose(const Rigid3d& a, const Rigid3d& b) {
  EXPECT_LT((a.translation - b.translation).norm(), 1e-9)
      << a.translation.transpose() << " vs " << b.translation.transpose();
  EXPECT_LT(a.rotation.angularDistance(b.rotation), 1e-9);
}

TEST(PlaceTrackedFrames, AFrameFollowsTheNewestPoseOfItsReferenceKeyframe) {
  // Tracked 0.5 m ahead of the keyframe; the mapper moved the keyframe since.
  const Rigid3d cam_from_reference = Turn(0.1, {0, 0, -0.5});
  const Rigid3d keyframe_now = Turn(0.3, {1, 2, 3});  // cam_from_world in the submap
  TrackedFramePose frame{10, 1000, kSubmap.value, false, Turn(0.0, {9, 9, 9}), kKeyframe.value, cam_from_reference};
  const std::vector<PoseRecord> poses = PlaceTrackedFrames({frame}, {{kKeyframe.value, {keyframe_now, 8}}}, {}, {});
  ASSERT_EQ(poses.size(), 1u);
  ExpectSamePose(poses[0].world_from_cam, (cam_from_reference * keyframe_now).Inverse());
  EXPECT_EQ(poses[0].component, -1);  // no placement: in its submap's own frame
  EXPECT_EQ(poses[0].t_ns, 1000);
}

TEST(PlaceTrackedFrames, AFrameWhoseReferenceIsUnknownKeepsItsTrackedPose) {
  const Rigid3d tracked = Turn(0.2, {4, 5, 6});
  TrackedFramePose culled{10, 0, kSubmap.value, false, tracked, MakeKeyframeId(kSubmap, 99).value, Turn(1, {1, 1, 1})};
  TrackedFramePose none{11, 0, kSubmap.value, false, tracked, -1, Turn(1, {1, 1, 1})};
  const std::vector<PoseRecord> poses = PlaceTrackedFrames({culled, none}, {{kKeyframe.value, {Rigid3d(), 8}}}, {}, {});
  ExpectSamePose(poses[0].world_from_cam, tracked);
  ExpectSamePose(poses[1].world_from_cam, tracked);
}

TEST(PlaceTrackedFrames, APlacedSubmapMovesItsFramesByItsSim3) {
  const Sim3d world_from_submap(2.5, Eigen::Quaterniond(Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitZ())), {10, -4, 1});
  const Rigid3d tracked = Turn(0.2, {4, 5, 6});
  TrackedFramePose frame{10, 0, kSubmap.value, false, tracked, -1, Rigid3d()};
  const std::vector<PoseRecord> poses = PlaceTrackedFrames({frame}, {}, {{kSubmap.value, {3, world_from_submap}}}, {});
  EXPECT_EQ(poses[0].component, 3);
  ExpectSamePose(poses[0].world_from_cam, Placed(world_from_submap, tracked));
}

TEST(PlaceTrackedFrames, EachFrameTakesTheCorrectionOfTheNearestRefinedKeyframe) {
  // Two keyframes at frames 0 and 100 of one placed submap; the pose graph shifted the first by
  // (1, 0, 0) and the second by (0, 5, 0) in the merged map.
  const Sim3d world_from_submap(2.0, Eigen::Quaterniond::Identity(), {0, 0, 0});
  const KeyframeId first = MakeKeyframeId(kSubmap, 0), second = MakeKeyframeId(kSubmap, 1);
  const Rigid3d first_cam_from_world = Turn(0, {0, 0, 0}), second_cam_from_world = Turn(0, {-10, 0, 0});
  std::map<int64_t, KeyframeInSubmap> keyframes{{first.value, {first_cam_from_world, 0}},
                                                {second.value, {second_cam_from_world, 100}}};
  const auto shifted = [&](const Rigid3d& cam_from_world, const Eigen::Vector3d& by) {
    const Rigid3d placed = Placed(world_from_submap, cam_from_world.Inverse());
    return Sim3d(2.0, placed.rotation, placed.translation + by);
  };
  std::map<int64_t, Sim3d> refined{{first.value, shifted(first_cam_from_world, {1, 0, 0})},
                                   {second.value, shifted(second_cam_from_world, {0, 5, 0})}};
  const Rigid3d tracked = Turn(0, {3, 0, 0});  // world_from_cam in the submap
  std::vector<TrackedFramePose> frames{{30, 0, kSubmap.value, false, tracked, -1, Rigid3d()},
                                       {70, 0, kSubmap.value, false, tracked, -1, Rigid3d()},
                                       {0, 0, kSubmap.value, true, first_cam_from_world.Inverse(), -1, Rigid3d()}};
  const std::vector<PoseRecord> poses =
      PlaceTrackedFrames(frames, keyframes, {{kSubmap.value, {0, world_from_submap}}}, refined);
  const Eigen::Vector3d placed = Placed(world_from_submap, tracked).translation;
  EXPECT_LT((poses[0].world_from_cam.translation - (placed + Eigen::Vector3d(1, 0, 0))).norm(), 1e-9);
  EXPECT_LT((poses[1].world_from_cam.translation - (placed + Eigen::Vector3d(0, 5, 0))).norm(), 1e-9);
  // The keyframe's own frame lands where the refinement put the keyframe.
  EXPECT_LT((poses[2].world_from_cam.translation - refined.at(first.value).translation).norm(), 1e-9);
}

}  // namespace
}  // namespace stitch
