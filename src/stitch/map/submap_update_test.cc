#include "stitch/map/submap_update.h"

#include <algorithm>

#include <gtest/gtest.h>

#include "stitch/testing/submap_updates.h"

namespace stitch {
namespace {

const SubmapId kSubmap = MakeSubmapId(1, 4);

// The mapper's side: a submap grown keyframe by keyframe; each keyframe observes 30 points, 20 of
// them shared with the previous keyframe.
struct Sender {
  Map map{kSubmap, ScalePyramid::From(OrbOptions())};
  Camera camera = Camera::Pinhole(640, 480, 400, 400, 320, 240);
  int revision = 0;

  Sender() { map.EnableRemovalJournal(); }

  SubmapUpdate AddKeyframe(uint32_t index) {
    testing::AddChainedKeyframe(&map, index);
    const LocalMapUpdate changes = MakeLocalMapUpdate(&map, MakeKeyframeId(kSubmap, index), ++revision, 0);
    return MakeKeyframeSubmapUpdate(map, MakeKeyframeId(kSubmap, index), camera, changes);
  }
};

void ExpectSameSubmap(const Map& expected, const Map& actual) {
  ASSERT_EQ(actual.num_keyframes(), expected.num_keyframes());
  ASSERT_EQ(actual.num_points(), expected.num_points());
  for (const auto& [id, keyframe] : expected.keyframes()) {
    const Keyframe* copy = actual.FindKeyframe(id);
    ASSERT_NE(copy, nullptr) << id;
    EXPECT_EQ(copy->points, keyframe.points) << id;
    EXPECT_LT((copy->cam_from_world.translation - keyframe.cam_from_world.translation).norm(), 1e-12);
    EXPECT_EQ(copy->keypoints.size(), keyframe.keypoints.size());
    EXPECT_EQ(cv::norm(copy->descriptors, keyframe.descriptors, cv::NORM_HAMMING), 0);
  }
  for (const auto& [id, point] : expected.points()) {
    const MapPoint* copy = actual.FindPoint(id);
    ASSERT_NE(copy, nullptr) << id;
    EXPECT_LT((copy->position - point.position).norm(), 1e-12);
    EXPECT_EQ(copy->observations, point.observations);
  }
}

TEST(SubmapUpdate, KeyframeUpdatesRebuildTheSubmap) {
  Sender sender;
  SubmapReplica receiver(kSubmap, ScalePyramid::From(OrbOptions()));
  for (uint32_t k = 0; k < 5; ++k) {
    const SubmapUpdate update = sender.AddKeyframe(k);
    EXPECT_EQ(update.new_keyframes.size(), 1u);
    EXPECT_TRUE(ApplySubmapUpdate(update, &receiver).empty());
  }
  ExpectSameSubmap(sender.map, receiver.map);
  EXPECT_EQ(receiver.map.FindKeyframe(MakeKeyframeId(kSubmap, 2))->covisibility.size(), 4u);
}

TEST(SubmapUpdate, PartsInAnyOrderAndTwiceGiveTheSameSubmap) {
  Sender sender;
  std::vector<SubmapUpdate> parts;
  for (uint32_t k = 0; k < 4; ++k) {
    for (SubmapUpdate& part : SplitSubmapUpdate(sender.AddKeyframe(k), 2500)) parts.push_back(std::move(part));
  }
  EXPECT_GT(parts.size(), 8u);  // small parts: each keyframe (about 1.9 kB) alone, points split
  SubmapReplica receiver(kSubmap, ScalePyramid::From(OrbOptions()));
  std::reverse(parts.begin(), parts.end());
  for (const SubmapUpdate& part : parts) ApplySubmapUpdate(part, &receiver);
  for (const SubmapUpdate& part : parts) ApplySubmapUpdate(part, &receiver);
  // Reversed parts leave associations to points that arrived later unset; the final state
  // (sent when the submap closes) repairs them.
  ApplySubmapUpdate(MakeFullSubmapUpdate(&sender.map, 99, true), &receiver);
  ExpectSameSubmap(sender.map, receiver.map);
  EXPECT_TRUE(receiver.closed);
  // A part that arrives after the final state changes nothing.
  for (const SubmapUpdate& part : parts) ApplySubmapUpdate(part, &receiver);
  ExpectSameSubmap(sender.map, receiver.map);
}

TEST(SubmapUpdate, ALostKeyframeIsReportedMissingAndRemovalsFollow) {
  Sender sender;
  SubmapReplica receiver(kSubmap, ScalePyramid::From(OrbOptions()));
  ApplySubmapUpdate(sender.AddKeyframe(0), &receiver);
  sender.AddKeyframe(1);  // lost on the way
  const std::vector<KeyframeId> missing = ApplySubmapUpdate(sender.AddKeyframe(2), &receiver);
  ASSERT_EQ(missing.size(), 1u);
  EXPECT_EQ(missing[0], MakeKeyframeId(kSubmap, 1));

  // The mapper culls keyframe 0: the next update's manifest and removals take it away here too.
  sender.map.RemoveKeyframe(MakeKeyframeId(kSubmap, 0));
  const SubmapUpdate final_state = MakeFullSubmapUpdate(&sender.map, 10, /*closed=*/true);
  EXPECT_TRUE(final_state.closed);
  EXPECT_TRUE(final_state.new_keyframes.empty());
  const std::vector<KeyframeId> still_missing = ApplySubmapUpdate(final_state, &receiver);
  EXPECT_EQ(receiver.map.FindKeyframe(MakeKeyframeId(kSubmap, 0)), nullptr);
  ASSERT_EQ(still_missing.size(), 1u);  // a final state carries no features: keyframe 1 stays missing
  EXPECT_EQ(receiver.map.num_keyframes(), 1u);
}

TEST(SubmapUpdate, ASubmapReopenedAfterItsFinalStateIsOpenAgain) {
  Sender sender;
  SubmapReplica receiver(kSubmap, ScalePyramid::From(OrbOptions()));
  ApplySubmapUpdate(sender.AddKeyframe(0), &receiver);
  ApplySubmapUpdate(sender.AddKeyframe(1), &receiver);
  ApplySubmapUpdate(MakeFullSubmapUpdate(&sender.map, ++sender.revision, /*closed=*/true), &receiver);
  EXPECT_TRUE(receiver.closed);
  // The tracker relocalized in it: new keyframes come with newer revisions.
  ApplySubmapUpdate(sender.AddKeyframe(2), &receiver);
  EXPECT_FALSE(receiver.closed);
  EXPECT_EQ(receiver.map.num_keyframes(), 3u);
}

// What the mapper sends when the merger asks for a closed submap's keyframes but not its state
// (LocalMapping::MakeResendUpdate): the keyframes alone, as revision 0.
TEST(SubmapUpdate, AClosedSubmapsKeyframeSentAgainAloneNeitherClosesNorReopensIt) {
  Sender sender;
  const SubmapUpdate first = sender.AddKeyframe(0);
  const SubmapUpdate lost = sender.AddKeyframe(1);
  SubmapUpdate again;
  again.submap = kSubmap;
  again.revision = 0;
  again.camera = lost.camera;
  again.new_keyframes = lost.new_keyframes;
  again.changes.submap = kSubmap;
  const SubmapUpdate final_state = MakeFullSubmapUpdate(&sender.map, ++sender.revision, /*closed=*/true);

  // Holding the final state: the keyframe joins, the submap stays closed and whole.
  SubmapReplica whole(kSubmap, ScalePyramid::From(OrbOptions()));
  ApplySubmapUpdate(first, &whole);
  ASSERT_EQ(ApplySubmapUpdate(final_state, &whole).size(), 1u);
  EXPECT_TRUE(ApplySubmapUpdate(again, &whole).empty());
  EXPECT_TRUE(whole.closed);
  ExpectSameSubmap(sender.map, whole.map);

  // Lacking it: the keyframe joins, and the submap is not taken for closed (its final state,
  // still to come, is what closes it).
  SubmapReplica partial(kSubmap, ScalePyramid::From(OrbOptions()));
  ApplySubmapUpdate(first, &partial);
  SubmapUpdate manifest_only = lost;  // the part with the keyframe was lost, the first arrived
  manifest_only.new_keyframes.clear();
  ASSERT_EQ(ApplySubmapUpdate(manifest_only, &partial).size(), 1u);
  EXPECT_TRUE(ApplySubmapUpdate(again, &partial).empty());
  EXPECT_FALSE(partial.closed);
  EXPECT_EQ(partial.map.num_keyframes(), 2u);
  ApplySubmapUpdate(final_state, &partial);
  EXPECT_TRUE(partial.closed);
  ExpectSameSubmap(sender.map, partial.map);
}

TEST(SubmapUpdate, AnUpdateOfAnotherSubmapChangesNothing) {
  Sender sender;
  SubmapReplica receiver(MakeSubmapId(1, 5), ScalePyramid::From(OrbOptions()));
  ApplySubmapUpdate(sender.AddKeyframe(0), &receiver);
  EXPECT_EQ(receiver.map.num_keyframes(), 0u);
  EXPECT_EQ(receiver.map.num_points(), 0u);
}

}  // namespace
}  // namespace stitch
