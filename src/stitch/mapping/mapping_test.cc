// The mapper's stages one at a time, on rendered views with exact poses and depth: triangulation
// of new points, fusion of duplicates, culling of recent points, local bundle adjustment and
// keyframe culling. The whole mapper on whole flights: src/stitch/pipeline.

#include <gtest/gtest.h>

#include "stitch/estimators/bundle_adjustment.h"
#include "stitch/mapping/culling.h"
#include "stitch/mapping/local_mapping.h"
#include "stitch/mapping/mapping_options.h"
#include "stitch/mapping/new_points.h"
#include "stitch/testing/default_vocabulary.h"
#include "stitch/testing/rendered_views.h"

namespace stitch {
namespace {

using testing::RenderedViews;
using testing::RotationErrorDeg;
using testing::TranslationError;

// The default flight's strip: 70 m above the terrain, 1 m a frame.
RenderedViews& Strip() {
  return testing::SharedStrip();
}

// A submap with keyframes at the given frames of the strip, each added at its true pose: its
// features matching earlier points observe them, every `stride`-th other feature with depth
// becomes a new point (at most `max_matches` matches each). The keyframes' bags of words are
// computed (the vocabulary's direct index serves triangulation's matching).
struct Scene {
  Map map{MakeSubmapId(0, 1), ScalePyramid::From(OrbOptions())};
  std::vector<KeyframeId> keyframes;
  std::vector<cv::Mat> depths;
};

Scene MakeScene(const std::vector<int>& frames, int stride = 1, int max_matches = 1 << 30, int later_stride = -1) {
  Scene scene;
  for (size_t i = 0; i < frames.size(); ++i) {
    cv::Mat depth;
    Frame frame = Strip().Render(frames[i], &depth);
    ComputeBow(testing::DefaultVocabulary(), &frame);
    scene.keyframes.push_back(Strip().AddKeyframe(&scene.map, frame, depth, static_cast<int>(i),
                                                  i == 0 || later_stride < 0 ? stride : later_stride, max_matches));
    scene.depths.push_back(depth);
  }
  return scene;
}

// Relative error of a point's depth in a keyframe against the rendered depth at its feature.
double DepthError(const Scene& scene, size_t keyframe, MapPointId id) {
  const Keyframe& kf = *scene.map.FindKeyframe(scene.keyframes[keyframe]);
  const MapPoint& point = *scene.map.FindPoint(id);
  const int feature = point.observations.at(kf.id);
  const cv::KeyPoint& keypoint = kf.keypoints[feature];
  const float truth = scene.depths[keyframe].at<float>(cvRound(keypoint.pt.y), cvRound(keypoint.pt.x));
  const double estimated = (kf.cam_from_world * point.position).z();
  return std::abs(estimated - truth) / truth;
}

// ---------------------------------------------------------------- triangulation

TEST(Triangulation, NewPointsLieWhereTheRenderedDepthSaysTheyAre) {
  // Keyframe 0 makes a point of every 4th feature; keyframe 1 (8 m on) matches those (and makes
  // one of its own).
  Scene scene = MakeScene({0, 8}, /*stride=*/4, /*max_matches=*/1 << 30, /*later_stride=*/1 << 30);
  const size_t before = scene.map.num_points();
  Map* map = &scene.map;
  const std::vector<MapPointId> created = TriangulateNewPoints(map, scene.keyframes[1], Strip().geometry(),
                                                               /*neighbours=*/20, MappingOptions().min_baseline_ratio);
  EXPECT_GT(created.size(), 100u);
  EXPECT_EQ(map->num_points(), before + created.size());
  int close = 0;
  for (MapPointId id : created) {
    const MapPoint& point = *map->FindPoint(id);
    EXPECT_EQ(point.observations.size(), 2u);
    close += DepthError(scene, 1, id) < 0.03;
  }
  EXPECT_GT(close, 0.9 * created.size()) << "points within 3% of the rendered depth";
}

TEST(Triangulation, NoBaselineNoNewPoints) {
  // Two keyframes at one pose (the same view, other sensor noise).
  Scene scene;
  for (int i = 0; i < 2; ++i) {
    cv::Mat depth;
    Frame frame = Strip().RenderPose(Strip().WorldFromCam(0), i, &depth);
    ComputeBow(testing::DefaultVocabulary(), &frame);
    scene.keyframes.push_back(Strip().AddKeyframe(&scene.map, frame, depth, i, i == 0 ? 4 : 1 << 30));
  }
  EXPECT_TRUE(TriangulateNewPoints(&scene.map, scene.keyframes[1], Strip().geometry(), 20, 0.01).empty());
}

TEST(Triangulation, AShortBaselineMakesNoPointsWhoseRaysAreNearlyParallel) {
  // 0.5 m apart 70 m up: a baseline of 0.007 of the depth passes the default pre-filter, but no
  // point of the terrain shows the 1.1 degrees of parallax each new point needs (0.4 here).
  const double ratio = MappingOptions().min_baseline_ratio;
  ASSERT_LT(ratio, 0.5 / 70);
  Scene scene;
  for (int i = 0; i < 2; ++i) {
    Rigid3d pose = Strip().WorldFromCam(0);
    pose.translation += pose.rotation * Eigen::Vector3d(0.5 * i, 0, 0);
    cv::Mat depth;
    Frame frame = Strip().RenderPose(pose, i, &depth);
    ComputeBow(testing::DefaultVocabulary(), &frame);
    scene.keyframes.push_back(Strip().AddKeyframe(&scene.map, frame, depth, i, i == 0 ? 4 : 1 << 30));
  }
  // Without the parallax check each of its hundreds of matches would become a point; a stray
  // false match (a point far off the terrain) may still pass, and recent-point culling takes it.
  // (8 m apart the same setting makes points: NewPointsLieWhereTheRenderedDepthSaysTheyAre.)
  EXPECT_LE(TriangulateNewPoints(&scene.map, scene.keyframes[1], Strip().geometry(), 20, ratio).size(), 5u);
}

// Keyframe 1 made every point anew (a duplicate of keyframe 0's) but for 30 shared ones that make
// the two covisible.
Scene TwoKeyframesWithDuplicates() {
  return MakeScene({0, 4}, /*stride=*/1, /*max_matches=*/30);
}

TEST(Fusion, TheSamePointMadeTwiceBecomesOne) {
  Scene scene = TwoKeyframesWithDuplicates();
  const size_t before = scene.map.num_points();
  const int fused = FuseWithNeighbours(&scene.map, scene.keyframes[1], Strip().geometry(), 20);
  EXPECT_GT(fused, 200);
  EXPECT_LT(scene.map.num_points(), before - 200);
  // Points observed by both keyframes now: far more than the 30 shared before.
  const Keyframe& kf1 = *scene.map.FindKeyframe(scene.keyframes[1]);
  int shared = 0;
  for (MapPointId p : kf1.points) {
    const MapPoint* point = p.valid() ? scene.map.FindPoint(p) : nullptr;
    shared += point && point->observations.count(scene.keyframes[0]);
  }
  EXPECT_GT(shared, 230);
}

// ---------------------------------------------------------------- culling of recent points

TEST(PointCulling, RecentPointsThatDoNotProveThemselvesAreRemoved) {
  Scene scene = MakeScene({0, 4, 8});
  Map* map = &scene.map;
  // Three points of keyframe 0: seen by one keyframe, by two, and by all three.
  MapPointId by_one, by_two, by_three;
  for (MapPointId p : map->FindKeyframe(scene.keyframes[0])->points) {
    const MapPoint* point = p.valid() ? map->FindPoint(p) : nullptr;
    if (!point) continue;
    const size_t n = point->observations.size();
    if (n == 1 && !by_one.valid()) by_one = p;
    if (n == 2 && !by_two.valid()) by_two = p;
    if (n == 3 && !by_three.valid()) by_three = p;
  }
  ASSERT_TRUE(by_one.valid() && by_two.valid() && by_three.valid());
  // One more: predicted in view 20 times and found once.
  MapPointId rarely_found;
  for (MapPointId p : map->FindKeyframe(scene.keyframes[1])->points) {
    if (p.valid() && p != by_one && p != by_two && p != by_three && map->FindPoint(p)->observations.size() == 3) {
      rarely_found = p;
      break;
    }
  }
  ASSERT_TRUE(rarely_found.valid());
  map->FindPoint(rarely_found)->visible = 20;
  map->FindPoint(rarely_found)->found = 1;

  RecentPoints recent;
  for (MapPointId p : {by_one, by_two, by_three, rarely_found}) recent.Add(p, /*created_at=*/0);
  const MappingOptions options;  // found ratio 0.25, observations 2
  const auto cull = [&](int keyframes_processed) {
    return recent.Cull(map, KeyframeId(), keyframes_processed, Strip().geometry(), options.point_min_found_ratio,
                       options.point_min_observations);
  };
  EXPECT_EQ(cull(1), 1) << "the rarely found one at once";
  EXPECT_EQ(map->FindPoint(rarely_found), nullptr);
  EXPECT_NE(map->FindPoint(by_one), nullptr) << "young points are given a chance";
  EXPECT_EQ(cull(2), 2) << "two keyframes on, points seen by at most two keyframes go";
  EXPECT_EQ(map->FindPoint(by_one), nullptr);
  EXPECT_EQ(map->FindPoint(by_two), nullptr);
  EXPECT_NE(map->FindPoint(by_three), nullptr);
  EXPECT_EQ(recent.size(), 1u);
  EXPECT_EQ(cull(3), 0);
  EXPECT_EQ(recent.size(), 0u) << "a point that survived three keyframes is no longer watched";
  EXPECT_NE(map->FindPoint(by_three), nullptr);
}

TEST(PointCulling, ANewKeyframeCountsItsChancesAndFinds) {
  Scene scene = MakeScene({0, 4});
  Map* map = &scene.map;
  RecentPoints recent;
  MapPointId observed, unobserved;
  const KeyframeId kf1 = scene.keyframes[1];
  for (const auto& [id, point] : map->points()) {
    PointInView view;
    const bool in_view = Strip().geometry().InView(point, map->FindKeyframe(kf1)->cam_from_world, &view);
    if (point.observations.count(kf1) && !observed.valid()) observed = id;
    if (!point.observations.count(kf1) && in_view && !unobserved.valid()) unobserved = id;
  }
  ASSERT_TRUE(observed.valid() && unobserved.valid());
  recent.Add(observed, 0);
  recent.Add(unobserved, 0);
  recent.Cull(map, kf1, 1, Strip().geometry(), 0.0, 0);
  EXPECT_EQ(map->FindPoint(observed)->visible, 2);
  EXPECT_EQ(map->FindPoint(observed)->found, 2);
  EXPECT_EQ(map->FindPoint(unobserved)->visible, 2);
  EXPECT_EQ(map->FindPoint(unobserved)->found, 1);
}

// ---------------------------------------------------------------- local bundle adjustment

TEST(LocalBundleAdjustment, PullsAPerturbedKeyframeAndItsPointsBackToTheTruth) {
  Scene scene = MakeScene({0, 5, 10, 15});
  Map* map = &scene.map;
  Keyframe* newest = map->FindKeyframe(scene.keyframes[3]);
  const Rigid3d truth = newest->cam_from_world;
  // 0.5 m and 1 degree off, and the points it made 2% too far.
  Rigid3d perturbed = truth.Inverse();
  perturbed.translation += Eigen::Vector3d(0.3, -0.4, 0.1);
  perturbed.rotation = perturbed.rotation * Eigen::Quaterniond(Eigen::AngleAxisd(M_PI / 180, Eigen::Vector3d::UnitX()));
  newest->cam_from_world = perturbed.Inverse();
  for (MapPointId p : newest->points) {
    MapPoint* point = p.valid() ? map->FindPoint(p) : nullptr;
    if (point && point->first_keyframe == newest->id) {
      point->position = perturbed * (1.02 * (truth * point->position));
    }
  }
  const BundleAdjustmentReport report = LocalBundleAdjustment(map, newest->id, Strip().k(), BundleAdjustmentOptions());
  EXPECT_TRUE(report.converged);
  EXPECT_GT(report.initial_rms_px, 3.0);
  EXPECT_LT(report.final_rms_px, 1.5);
  EXPECT_GE(report.keyframes_free, 2);
  // The rendered depth at a feature's rounded pixel is not the exact optimum: a few pixels'
  // worth at 70 m.
  EXPECT_LT(TranslationError(newest->cam_from_world, truth), 0.2);
  EXPECT_LT(RotationErrorDeg(newest->cam_from_world, truth), 0.3);
}

// ---------------------------------------------------------------- keyframe culling

// Six keyframes of one view (only the sensor noise differs): all but the first and the newest
// add nothing.
Scene SameViewSixTimes() {
  Scene scene;
  for (int i = 0; i < 6; ++i) {
    cv::Mat depth;
    const Frame frame = Strip().RenderPose(Strip().WorldFromCam(0), i, &depth);
    scene.keyframes.push_back(Strip().AddKeyframe(&scene.map, frame, depth, i, i == 0 ? 1 : 1 << 30));
  }
  return scene;
}

TEST(KeyframeCulling, RemovesKeyframesWhosePointsOthersSee) {
  Scene scene = SameViewSixTimes();
  const Map before = scene.map;
  const std::vector<CulledKeyframe> culled =
      CullRedundantKeyframes(&scene.map, scene.keyframes[5], /*keep=*/KeyframeId(), 0.9);
  ASSERT_FALSE(culled.empty());
  // The keyframe to keep (the submap's first, in the mapper) is kept even when redundant.
  Map again = before;
  const KeyframeId keep = culled.front().id;
  for (const CulledKeyframe& c : CullRedundantKeyframes(&again, scene.keyframes[5], keep, 0.9)) EXPECT_NE(c.id, keep);
  EXPECT_NE(again.FindKeyframe(keep), nullptr);
  for (const CulledKeyframe& c : culled) {
    EXPECT_NE(c.id, scene.keyframes[5]) << "the new keyframe is never culled";
    EXPECT_EQ(scene.map.FindKeyframe(c.id), nullptr);
    EXPECT_LT(TranslationError(c.cam_from_world, Strip().WorldFromCam(0).Inverse()), 1e-9);
  }
  EXPECT_GE(scene.map.num_keyframes(), 2u);
}

TEST(KeyframeCulling, ACulledKeyframeIsPosedAgainWhereTheRefinedPointsPutIt) {
  Scene scene = SameViewSixTimes();
  const std::vector<CulledKeyframe> culled =
      CullRedundantKeyframes(&scene.map, scene.keyframes[5], /*keep=*/KeyframeId(), 0.9);
  ASSERT_FALSE(culled.empty());
  const CulledKeyframe& record = culled.front();
  ASSERT_GE(record.observations.size(), 100u);
  // Later adjustment moves the whole map (2 degrees and 1.2 m) but not the culled keyframe, whose
  // pose through its parent is the one it had (here exact): its points say where it is now.
  const Rigid3d moved(Eigen::Quaterniond(Eigen::AngleAxisd(2 * M_PI / 180, Eigen::Vector3d(1, 2, 3).normalized())),
                      Eigen::Vector3d(1.0, -0.5, 0.6));  // new_world_from_old_world
  std::vector<MapPointId> ids;
  for (const auto& [id, point] : scene.map.points()) ids.push_back(id);
  for (MapPointId id : ids) scene.map.FindPoint(id)->position = moved * scene.map.FindPoint(id)->position;
  const Rigid3d then = record.cam_from_world;
  const Rigid3d now = then * moved.Inverse();
  ASSERT_GT(TranslationError(then, now), 1.0);
  const Rigid3d reposed = PoseOnRefinedMap(scene.map, record, then, Strip().geometry());
  // (The rendered depth at a feature's rounded pixel is not exact: centimetres at 70 m.)
  EXPECT_LT(TranslationError(reposed, now), 0.1);
  EXPECT_LT(RotationErrorDeg(reposed, now), 0.05);

  // Where too few of its points are left (fused away or culled), it keeps the pose it had.
  CulledKeyframe few = record;
  few.observations.resize(20);
  EXPECT_LT(TranslationError(PoseOnRefinedMap(scene.map, few, then, Strip().geometry()), then), 1e-12);
  // Where most of them no longer agree (another place's points), it keeps the pose it is given,
  // even one the agreeing 40% would refine.
  CulledKeyframe disagreeing = record;
  for (size_t o = 0; o < disagreeing.observations.size(); ++o) {
    if (o % 5 < 3) disagreeing.observations[o].undistorted += Eigen::Vector2f(o % 2 ? 12 : -12, 9);
  }
  const Rigid3d kept = PoseOnRefinedMap(scene.map, disagreeing, now, Strip().geometry());
  EXPECT_EQ(kept.translation, now.translation);
  EXPECT_EQ(kept.rotation.coeffs(), now.rotation.coeffs());
}

TEST(KeyframeCulling, KeepsKeyframesThatSeeTheirOwnPartOfTheGround) {
  // 15 m apart: each keyframe sees ground the others see little of.
  Scene scene = MakeScene({0, 15, 30, 45, 60, 75});
  EXPECT_TRUE(CullRedundantKeyframes(&scene.map, scene.keyframes[5], scene.keyframes[0], 0.9).empty());
  EXPECT_EQ(scene.map.num_keyframes(), 6u);
}

// ---------------------------------------------------------------- the per-keyframe protocol

// The tracker's initial map: the points keyframe 0 made, as the tracker sends them.
std::vector<MapPoint> InitialPoints(const Scene& scene) {
  std::vector<MapPoint> initial;
  for (const auto& [id, point] : scene.map.points()) {
    if (point.first_keyframe != scene.keyframes[0]) continue;
    initial.push_back(point);
    initial.back().observations.clear();
  }
  return initial;
}

// What the tracker sends for keyframe `i`: its features and associations with the points it knows.
Keyframe AsTheTrackerSendsIt(const Scene& scene, size_t i) {
  Keyframe keyframe = *scene.map.FindKeyframe(scene.keyframes[i]);
  for (MapPointId& p : keyframe.points) {
    if (p.valid() && scene.map.FindPoint(p)->first_keyframe != scene.keyframes[0]) p = MapPointId();
  }
  return keyframe;
}

TEST(LocalMapping, EachKeyframeGivesTheTrackerAndTheMergerTheirUpdates) {
  // The tracker's initial map holds a point for every 4th feature of keyframe 0; the rest is left
  // for the mapper to triangulate.
  const Scene scene = MakeScene({0, 6, 12}, /*stride=*/4);
  LocalMapping mapping(MappingOptions(), Strip().sequence().camera(), OrbOptions(), &testing::DefaultVocabulary());
  const std::vector<MapPoint> initial = InitialPoints(scene);
  for (size_t i = 0; i < scene.keyframes.size(); ++i) {
    const Keyframe keyframe = AsTheTrackerSendsIt(scene, i);
    const MappedKeyframe mapped = mapping.MapKeyframe(keyframe, i == 0 ? initial : std::vector<MapPoint>());
    EXPECT_EQ(mapped.report.keyframe, keyframe.id);
    EXPECT_FALSE(mapped.closed_final);
    EXPECT_EQ(mapped.for_tracker.last_keyframe, keyframe.id);
    EXPECT_EQ(mapped.for_merger.submap, scene.map.id());
    ASSERT_EQ(mapped.for_merger.new_keyframes.size(), 1u);
    EXPECT_EQ(mapped.for_merger.new_keyframes[0].id, keyframe.id);
    if (i > 0) {
      EXPECT_GT(mapped.report.new_points, 50) << "keyframe " << i;
    }
  }
  EXPECT_EQ(mapping.map()->num_keyframes(), 3u);
  // A keyframe sent again (the tracker did not hear back in time): the tracker is answered, the
  // merger is not sent it twice, nothing is mapped twice.
  const MappedKeyframe again = mapping.MapKeyframe(*scene.map.FindKeyframe(scene.keyframes[1]), {});
  EXPECT_TRUE(again.report.duplicate);
  EXPECT_EQ(again.for_tracker.last_keyframe, scene.keyframes[1]);
  EXPECT_FALSE(again.for_merger.submap.valid());
  EXPECT_EQ(mapping.map()->num_keyframes(), 3u);
  // A keyframe of another submap closes this one: its final state comes first.
  Keyframe next = *scene.map.FindKeyframe(scene.keyframes[2]);
  next.id = MakeKeyframeId(MakeSubmapId(0, 2), 0);
  const MappedKeyframe mapped = mapping.MapKeyframe(next, {});
  ASSERT_TRUE(mapped.closed_final);
  EXPECT_TRUE(mapped.closed_final->closed);
  EXPECT_EQ(mapped.closed_final->submap, scene.map.id());
  EXPECT_EQ(mapping.closed_maps().size(), 1u);
}

// A tracker that does not wait gets the new points as soon as they are made; when the next
// keyframe already waits, fusion, adjustment and culling are left to it.
TEST(LocalMapping, NewPointsGoOutFirstAndAWaitingKeyframeDefersTheRest) {
  const Scene scene = MakeScene({0, 6, 12}, /*stride=*/4);
  LocalMapping mapping(MappingOptions(), Strip().sequence().camera(), OrbOptions(), &testing::DefaultVocabulary());
  std::vector<LocalMapUpdate> early;
  MappingHooks hooks;
  hooks.new_points_made = [&](const LocalMapUpdate& update) { early.push_back(update); };
  mapping.MapKeyframe(AsTheTrackerSendsIt(scene, 0), InitialPoints(scene), hooks);
  const MappedKeyframe second = mapping.MapKeyframe(AsTheTrackerSendsIt(scene, 1), {}, hooks);
  EXPECT_FALSE(second.report.deferred);
  ASSERT_EQ(early.size(), 1u);  // keyframe 0 made no point of its own
  EXPECT_EQ(static_cast<int>(early[0].points.size()), second.report.new_points);
  EXPECT_FALSE(early[0].last_keyframe.valid());  // the keyframe is not done yet

  hooks.next_waiting = [] { return true; };
  const MappedKeyframe third = mapping.MapKeyframe(AsTheTrackerSendsIt(scene, 2), {}, hooks);
  EXPECT_TRUE(third.report.deferred);
  EXPECT_GT(third.report.new_points, 50);
  EXPECT_EQ(third.report.fused, 0);
  EXPECT_EQ(third.report.bundle_adjustment.points, 0);
  EXPECT_TRUE(third.report.culled_keyframes.empty());
  EXPECT_EQ(third.for_tracker.last_keyframe, scene.keyframes[2]);  // still answered
  ASSERT_EQ(early.size(), 2u);
  EXPECT_EQ(static_cast<int>(early[1].points.size()), third.report.new_points);
  bool has_keyframe = false;
  for (const auto& [id, points] : early[1].associations) has_keyframe |= id == scene.keyframes[2];
  EXPECT_TRUE(has_keyframe);
}

}  // namespace
}  // namespace stitch
