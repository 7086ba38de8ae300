#include "services/common/map_convert.h"

#include <cmath>

#include <gtest/gtest.h>

#include "stitch/util/error.h"

namespace stitch {
namespace {

const SubmapId kSubmap = MakeSubmapId(3, 7);
const ScalePyramid kPyramid = ScalePyramid::From(OrbOptions());
const Camera kCamera = Camera::Pinhole(640, 480, 450, 450, 319.5, 239.5);

Keyframe MakeKeyframe(uint32_t index, int features) {
  Keyframe k;
  k.id = MakeKeyframeId(kSubmap, index);
  k.frame_index = 100 + static_cast<int>(index);
  k.t_ns = 1'000'000'000LL * index;
  k.cam_from_world = Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.1 * index, Eigen::Vector3d::UnitZ())),
                             Eigen::Vector3d(0.5, -0.25, 2.0));
  k.descriptors = cv::Mat(features, 32, CV_8U);
  cv::randu(k.descriptors, 0, 256);
  for (int i = 0; i < features; ++i) {
    cv::KeyPoint kp(12.125f + i % 600, 30.5f + i / 600, 31.0f, 45.0f);
    kp.octave = i % kPyramid.num_levels;
    k.keypoints.push_back(kp);
    k.points.push_back(i % 3 == 0 ? MakeMapPointId(kSubmap, static_cast<uint32_t>(i)) : MapPointId());
  }
  return k;
}

MapPoint MakePoint(uint32_t index) {
  MapPoint p;
  p.id = MakeMapPointId(kSubmap, index);
  p.position = Eigen::Vector3d(index, -1.5, 4.25);
  p.normal = Eigen::Vector3d(0, 0, 1);
  p.min_distance = 1;
  p.max_distance = 9;
  p.descriptor[0] = static_cast<uint8_t>(index);
  return p;
}

SubmapUpdate MakeUpdate() {
  SubmapUpdate update;
  update.submap = kSubmap;
  update.revision = 12;
  update.camera = kCamera;
  update.new_keyframes = {MakeKeyframe(1, 1000), MakeKeyframe(2, 900)};
  update.changes.submap = kSubmap;
  update.changes.revision = 12;
  update.changes.keyframe_poses = {{MakeKeyframeId(kSubmap, 1), Rigid3d()}};
  update.changes.associations = {{MakeKeyframeId(kSubmap, 1), {MapPointId(), MakeMapPointId(kSubmap, 3)}}};
  for (uint32_t i = 0; i < 1200; ++i) update.changes.points.push_back(MakePoint(i));
  update.changes.removed_points = {MakeMapPointId(kSubmap, 5000)};
  update.changes.removed_keyframes = {MakeKeyframeId(kSubmap, 0)};
  update.manifest = {MakeKeyframeId(kSubmap, 1), MakeKeyframeId(kSubmap, 2)};
  return update;
}

TEST(MapConvert, KeyframeRoundTripsToAnEighthOfAPixel) {
  const Keyframe sent = MakeKeyframe(4, 300);
  const ReceivedKeyframe received = FromMessage(ToMessage(sent, kCamera, {MakePoint(9)}), kPyramid);
  EXPECT_EQ(received.keyframe.id, sent.id);
  EXPECT_EQ(received.keyframe.points, sent.points);
  ASSERT_EQ(received.keyframe.keypoints.size(), 300u);
  EXPECT_FLOAT_EQ(received.keyframe.keypoints[0].pt.x, 12.125f);
  EXPECT_EQ(received.keyframe.keypoints[7].octave, 7);
  EXPECT_EQ(cv::norm(received.keyframe.descriptors, sent.descriptors, cv::NORM_HAMMING), 0);
  ASSERT_EQ(received.new_points.size(), 1u);
  EXPECT_EQ(received.new_points[0].id, MakeMapPointId(kSubmap, 9));
  EXPECT_EQ(received.camera.width(), 640);
}

TEST(MapConvert, SubmapUpdateTravelsInPartsUnderTheLimit) {
  const SubmapUpdate sent = MakeUpdate();
  const std::vector<stitch::submap_update_t> messages = ToMessages(sent, 60000);
  ASSERT_GE(messages.size(), 3u);  // points (86 kB) in two parts, then each keyframe alone
  size_t keyframes = 0, points = 0;
  for (const auto& m : messages) {
    EXPECT_LE(static_cast<size_t>(m.getEncodedSize()), 60000u);
    EXPECT_EQ(m.num_parts, static_cast<int>(messages.size()));
    const SubmapUpdate part = FromMessage(m, kPyramid);
    EXPECT_EQ(part.submap, kSubmap);
    EXPECT_EQ(part.revision, 12);
    keyframes += part.new_keyframes.size();
    points += part.changes.points.size();
    if (m.part == 0) {
      EXPECT_EQ(part.manifest, sent.manifest);
      EXPECT_EQ(part.changes.removed_keyframes, sent.changes.removed_keyframes);
      EXPECT_EQ(part.changes.keyframe_poses.size(), 1u);
    }
  }
  EXPECT_EQ(keyframes, 2u);
  EXPECT_EQ(points, 1200u);
}

TEST(MapConvert, InconsistentSubmapUpdatesAreRejectedWithAReason) {
  const std::vector<stitch::submap_update_t> parts = ToMessages(MakeUpdate(), 1'000'000);
  ASSERT_EQ(parts.size(), 2u);  // the changes, then the keyframes
  stitch::submap_update_t message = parts[0];
  message.keyframes = parts[1].keyframes;
  message.num_keyframes = parts[1].num_keyframes;
  auto expect_rejected = [&](stitch::submap_update_t m, const std::string& reason) {
    try {
      FromMessage(m, kPyramid);
      ADD_FAILURE() << "accepted: " << reason;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(reason), std::string::npos) << e.what();
    }
  };
  stitch::submap_update_t foreign = message;
  foreign.manifest_keyframe_ids[0] = MakeKeyframeId(MakeSubmapId(3, 8), 1).value;
  expect_rejected(foreign, "another submap");
  stitch::submap_update_t short_descriptors = message;
  short_descriptors.keyframes[0].num_descriptor_bytes -= 32;
  expect_rejected(short_descriptors, "descriptors for");
  stitch::submap_update_t not_finite = message;
  not_finite.points[0].position[1] = std::nanf("");
  expect_rejected(not_finite, "non-finite");
  // Finite but no map's (#45: these passed uncounted): a point at 1e30, a point index of 2^30 in
  // a point or an association, a keyframe's camera 1e30 away.
  stitch::submap_update_t far_point = message;
  far_point.points[0].position[0] = 1e30f;
  expect_rejected(far_point, "outside any map");
  stitch::submap_update_t huge_index = message;
  huge_index.points[0].point_index = 1 << 30;
  expect_rejected(huge_index, "past any map's");
  stitch::submap_update_t huge_association = message;
  ASSERT_FALSE(huge_association.associations.empty());
  ASSERT_FALSE(huge_association.associations[0].point_index.empty());
  huge_association.associations[0].point_index[0] = 1 << 30;
  expect_rejected(huge_association, "past any map's");
  stitch::submap_update_t far_camera = message;
  ASSERT_FALSE(far_camera.cam_from_submap.empty());
  far_camera.cam_from_submap[0].translation[2] = 1e30;
  expect_rejected(far_camera, "outside any map");
  stitch::submap_update_t far_keyframe = message;
  far_keyframe.keyframes[0].cam_from_submap.translation[0] = -1e30;
  expect_rejected(far_keyframe, "outside any map");
  stitch::submap_update_t bad_id = message;
  bad_id.submap_id = MakeKeyframeId(kSubmap, 3).value;
  expect_rejected(bad_id, "invalid submap id");
}

}  // namespace
}  // namespace stitch
