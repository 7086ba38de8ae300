// The tracker's stages one at a time, on rendered views with exact poses and depth (the way
// COLMAP's incremental mapper tests step through a synthesized scene): when one breaks, its test
// says which. The whole tracker on whole flights: src/stitch/pipeline.

#include <cmath>

#include <set>

#include <gtest/gtest.h>

#include "stitch/testing/default_vocabulary.h"
#include "stitch/testing/rendered_views.h"
#include "stitch/tracking/frame_placer.h"
#include "stitch/tracking/initializer.h"
#include "stitch/tracking/keyframe_decision.h"
#include "stitch/tracking/relocalizer.h"
#include "stitch/tracking/submap_store.h"
#include "stitch/tracking/tracking.h"

namespace stitch {
namespace {

using testing::DefaultVocabulary;
using testing::RenderedViews;
using testing::RotationErrorDeg;
using testing::TranslationError;

// The default flight's strip: 70 m above the terrain, 1 m a frame.
RenderedViews& Strip() {
  return testing::SharedStrip();
}

OrbExtractor& InitializationExtractor() {
  static OrbExtractor* extractor = new OrbExtractor([] {
    OrbOptions options;
    options.num_features *= 2;  // as the tracker initializes
    return options;
  }());
  return *extractor;
}

double AngleBetweenDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::acos(std::clamp(a.normalized().dot(b.normalized()), -1.0, 1.0)) * 180.0 / M_PI;
}

// ---------------------------------------------------------------- initialization

// Two views at `a` and `b` (world_from_cam) through a fresh initializer.
Initializer::Result InitializeBetween(RenderedViews& views, const Rigid3d& a, const Rigid3d& b) {
  Initializer initializer(TrackingOptions(), &views.geometry(), &DefaultVocabulary());
  const Initializer::Result first =
      initializer.Add(views.RenderPose(a, 0, nullptr, &InitializationExtractor()), MakeSubmapId(0, 1));
  EXPECT_FALSE(first.map);
  EXPECT_TRUE(initializer.has_reference());
  return initializer.Add(views.RenderPose(b, 1, nullptr, &InitializationExtractor()), MakeSubmapId(0, 1));
}

// The initial map against the truth: keyframe 0 is the first view, keyframe 1 the second; the
// translation is known up to scale.
void ExpectTrueRelativePose(const Initializer::Result& result, const Rigid3d& a, const Rigid3d& b,
                            double max_rotation_error_deg = 0.5) {
  ASSERT_TRUE(result.map) << result.detail;
  const Map& map = *result.map;
  EXPECT_EQ(map.num_keyframes(), 2u);
  EXPECT_GE(static_cast<int>(map.num_points()), TrackingOptions().init_min_matches);
  const KeyframeId id0 = MakeKeyframeId(map.id(), 0), id1 = MakeKeyframeId(map.id(), 1);
  EXPECT_NEAR(map.MedianDepth(id0), 1.0, 1e-6) << "the submap's scale is unit median depth";
  const Rigid3d truth = b.Inverse() * a;  // cam2_from_cam1
  const Rigid3d& estimated = map.FindKeyframe(id1)->cam_from_world;
  EXPECT_LT(RotationErrorDeg(estimated, truth), max_rotation_error_deg);
  EXPECT_LT(AngleBetweenDeg(estimated.translation, truth.translation), 5.0);
  ASSERT_TRUE(result.frame.cam_from_world);
  EXPECT_LT(TranslationError(*result.frame.cam_from_world, estimated), 1e-12) << "the frame is keyframe 1";
  EXPECT_EQ(result.frame.CountTracked(), map.FindKeyframe(id1)->CountPoints());
}

TEST(Initializer, FlatGroundSeenFromAboveInitializesFromAHomography) {
  SyntheticOptions options = RenderedViews::Strip(40);
  options.world.relief_m = 0;
  options.world.num_buildings = 0;
  RenderedViews views(options);
  const Rigid3d a = views.WorldFromCam(0), b = views.WorldFromCam(12);
  const Initializer::Result result = InitializeBetween(views, a, b);
  ExpectTrueRelativePose(result, a, b);
  EXPECT_NE(result.detail.find("homography"), std::string::npos) << result.detail;
}

TEST(Initializer, BuildingsSeenFromLowInitializeFromAnEssentialMatrix) {
  SyntheticOptions options = RenderedViews::Strip(40);
  options.flight.altitude_m = 30;
  options.world.relief_m = 0;
  options.world.num_buildings = 200;
  options.world.building_min_height_m = 10;
  options.world.building_max_height_m = 20;
  RenderedViews views(options);
  const Rigid3d a = views.WorldFromCam(0), b = views.WorldFromCam(3);
  const Initializer::Result result = InitializeBetween(views, a, b);
  ExpectTrueRelativePose(result, a, b);
  EXPECT_NE(result.detail.find("essential"), std::string::npos) << result.detail;
}

TEST(Initializer, AStillCameraNeverInitializes) {
  Initializer initializer(TrackingOptions(), &Strip().geometry(), &DefaultVocabulary());
  const Rigid3d still = Strip().WorldFromCam(20);
  for (int i = 0; i < 8; ++i) {
    // The same view again and again, only the sensor noise differs: no parallax.
    const Initializer::Result result =
        initializer.Add(Strip().RenderPose(still, i, nullptr, &InitializationExtractor()), MakeSubmapId(0, 1));
    EXPECT_FALSE(result.map) << "frame " << i << ": " << result.detail;
    EXPECT_NE(result.reason, TrackingReason::kNone);
  }
}

// The log and frames.tsv say how a map began: the model, its share of the score, points,
// parallax, and the attempts with the same reference it refused before (and why the last was).
TEST(Initializer, AnInitializationSaysItsModelScoresPointsParallaxAndTheAttemptsItRefused) {
  Initializer initializer(TrackingOptions(), &Strip().geometry(), &DefaultVocabulary());
  const Rigid3d still = Strip().WorldFromCam(20);
  for (int i = 0; i < 3; ++i) {
    const Initializer::Result waiting =
        initializer.Add(Strip().RenderPose(still, i, nullptr, &InitializationExtractor()), MakeSubmapId(0, 1));
    ASSERT_FALSE(waiting.map) << waiting.detail;
  }
  const Initializer::Result result = initializer.Add(
      Strip().RenderPose(Strip().WorldFromCam(32), 3, nullptr, &InitializationExtractor()), MakeSubmapId(0, 1));
  ASSERT_TRUE(result.map) << result.detail;
  const std::string& detail = result.detail;
  EXPECT_EQ(detail.rfind("initialized from a homography (homography's share of the score 0.", 0), 0u) << detail;
  EXPECT_NE(detail.find("choosing it above 0.40"), std::string::npos) << detail;
  EXPECT_NE(detail.find(" with " + std::to_string(result.map->num_points()) + " points"), std::string::npos) << detail;
  EXPECT_NE(detail.find(", parallax "), std::string::npos) << detail;
  EXPECT_NE(detail.find("3 frames after its reference"), std::string::npos) << detail;
  EXPECT_NE(detail.find("; 2 attempts refused before it, the last: "), std::string::npos) << detail;
  // The still frames' refusal names the model scored and its share.
  EXPECT_NE(detail.find("the last: homography (homography's share of the score"), std::string::npos) << detail;
}

// The gate's `road` car: 1.5 m up, looking ahead, 0.9 m a frame at 10 Hz along a street between
// buildings.
SyntheticOptions RoadFlight() {
  SyntheticOptions options;
  options.flight.path = "road";
  options.flight.num_frames = 400;
  options.flight.fps = 10;
  options.flight.num_strips = 3;
  options.flight.strip_length_m = 110;
  options.flight.altitude_m = 1.5;
  options.flight.camera_pitch_deg = 88;
  options.flight.attitude_jitter_deg = 0.3;
  options.flight.altitude_jitter_m = 0.03;
  options.world.relief_m = 0;
  options.world.visibility_m = 200;
  return options;
}

// The first map `tracking` makes from frames `first`..`last` of `views` (at their true poses),
// and the frame it began at (-1: none).
Initializer::Result FirstMap(RenderedViews& views, const TrackingOptions& tracking, int first, int last, int* at,
                             std::vector<cv::Mat>* depths = nullptr) {
  Initializer initializer(tracking, &views.geometry(), &DefaultVocabulary());
  for (int i = first; i <= last; ++i) {
    cv::Mat depth;
    Initializer::Result result = initializer.Add(
        views.RenderPose(views.WorldFromCam(i), i, depths ? &depth : nullptr, &InitializationExtractor()),
        MakeSubmapId(0, 1));
    if (depths) depths->push_back(depth);
    if (result.map) {
      *at = i;
      return result;
    }
  }
  *at = -1;
  return Initializer::Result();
}

// A car's camera on a straight street. Its features grow out of pyramid level 0 within a few
// frames, so level 0 alone keeps too few matches to hold a reference that long: the reference
// is matched across levels instead (tracker.tracking.init_across_levels), and the map begins
// from an essential matrix, with the true motion. Without that rule the reference is replaced
// again and again and no map begins in these frames.
TEST(Initializer, ACameraMovingTowardTheSceneMatchesItsReferenceAcrossLevels) {
  RenderedViews views(RoadFlight());
  TrackingOptions across_levels;
  across_levels.init_across_levels = true;
  int at = -1;
  const Initializer::Result result = FirstMap(views, across_levels, 0, 12, &at);
  ASSERT_TRUE(result.map) << "no map in 13 frames";
  EXPECT_NE(result.detail.find("initialized from an essential matrix"), std::string::npos) << result.detail;
  EXPECT_NE(result.detail.find("the essential matrix alone, the camera moving toward the scene"), std::string::npos)
      << result.detail;
  EXPECT_NE(result.detail.find("matched across pyramid levels"), std::string::npos) << result.detail;
  ASSERT_FALSE(result.earlier.empty());
  ASSERT_TRUE(result.earlier.front().is_reference);
  // A camera moving along its axis tells its turn less well than one moving across it (0.6
  // degrees here, from 7 frames).
  ExpectTrueRelativePose(result, views.WorldFromCam(result.earlier.front().frame_index), views.WorldFromCam(at), 1.0);

  const Initializer::Result without = FirstMap(views, TrackingOptions(), 0, 12, &at);
  EXPECT_FALSE(without.map) << "frame " << at << ": " << without.detail;
}

// The car's last street (from frame 279): a quarter of the features the reference matches at its
// tenth frame are look-alikes along their epipolar lines (a facade's repeated windows), which two
// views cannot tell, and they put their points about twice too far: the frames tracked next
// moved twice as fast as the car. The frames the map waited through see those points elsewhere
// than they project, and they are dropped: the points' depths agree with the true ones at the
// true baseline's scale (median ratio 2.2 without the rule).
TEST(Initializer, PointsTheFramesItWaitedThroughSeeElsewhereAreDropped) {
  RenderedViews views(RoadFlight());
  TrackingOptions across_levels;
  across_levels.init_across_levels = true;
  int at = -1;
  std::vector<cv::Mat> depths;
  const Initializer::Result result = FirstMap(views, across_levels, 279, 295, &at, &depths);
  ASSERT_TRUE(result.map) << "no map";
  EXPECT_NE(result.detail.find("points the frames it waited through saw elsewhere were dropped"), std::string::npos)
      << result.detail;
  const Map& map = *result.map;
  const Keyframe& k0 = *map.FindKeyframe(MakeKeyframeId(map.id(), 0));
  const Keyframe& k1 = *map.FindKeyframe(MakeKeyframeId(map.id(), 1));
  const int reference = result.earlier.front().frame_index;
  const Rigid3d truth = views.WorldFromCam(at).Inverse() * views.WorldFromCam(reference);
  const double units_per_metre = k1.cam_from_world.translation.norm() / truth.translation.norm();
  const cv::Mat& depth = depths[static_cast<size_t>(reference - 279)];
  std::vector<double> ratios;
  for (size_t f = 0; f < k0.points.size(); ++f) {
    if (!k0.points[f].valid()) continue;
    const double estimated = (k0.cam_from_world * map.FindPoint(k0.points[f])->position).z() / units_per_metre;
    // A corner's pixel may lie on either side of a depth edge: the true depth nearest the estimate
    // within 3 pixels.
    double best = 1e9;
    const cv::Point2f& pixel = k0.keypoints[f].pt;
    for (int dy = -3; dy <= 3; ++dy) {
      for (int dx = -3; dx <= 3; ++dx) {
        const int y = std::clamp(static_cast<int>(pixel.y + 0.5f) + dy, 0, depth.rows - 1);
        const int x = std::clamp(static_cast<int>(pixel.x + 0.5f) + dx, 0, depth.cols - 1);
        const float d = depth.at<float>(y, x);
        if (d > 0 && std::abs(std::log(estimated / d)) < std::abs(std::log(best))) best = estimated / d;
      }
    }
    ratios.push_back(best);
  }
  ASSERT_GE(ratios.size(), 50u);
  std::nth_element(ratios.begin(), ratios.begin() + ratios.size() / 2, ratios.end());
  EXPECT_NEAR(ratios[ratios.size() / 2], 1.0, 0.1) << "the points' depth over the true depth, at the baseline's scale";
}

TEST(Initializer, AFrameWithoutFeaturesForgetsTheReference) {
  Initializer initializer(TrackingOptions(), &Strip().geometry(), &DefaultVocabulary());
  initializer.Add(Strip().RenderPose(Strip().WorldFromCam(0), 0, nullptr, &InitializationExtractor()),
                  MakeSubmapId(0, 1));
  ASSERT_TRUE(initializer.has_reference());
  Frame black =
      MakeFrame(cv::Mat::zeros(480, 640, CV_8UC1), 1, 0, &InitializationExtractor(), Strip().geometry().undistorter);
  const Initializer::Result result = initializer.Add(std::move(black), MakeSubmapId(0, 1));
  EXPECT_EQ(result.reason, TrackingReason::kTooFewFeatures);
  EXPECT_FALSE(initializer.has_reference());
}

// ---------------------------------------------------------------- frame placement

// A map of one keyframe (frame `index`, points at true depth) and that frame as the last
// tracked frame (tracking every point of the keyframe).
struct OneKeyframe {
  Map map{SubmapId(), ScalePyramid()};
  Frame last;
  KeyframeId keyframe;
};

OneKeyframe MakeOneKeyframe(int index) {
  OneKeyframe scene;
  cv::Mat depth;
  scene.last = Strip().Render(index, &depth);
  Keyframe keyframe;
  scene.map = Strip().MapFromFrame(scene.last, depth, &keyframe);
  scene.keyframe = keyframe.id;
  scene.last.points = keyframe.points;
  Keyframe* in_map = scene.map.FindKeyframe(keyframe.id);
  in_map->bow = DefaultVocabulary().Transform(in_map->descriptors, &in_map->bow_features);
  return scene;
}

// The true velocity cam_from_world(k) * world_from_cam(k - 1) between two frames of the strip.
Rigid3d TrueVelocity(int from, int to) {
  return Strip().WorldFromCam(to).Inverse() * Strip().WorldFromCam(from);
}

// Within `metres` and `degrees` of the truth (at 70 m above the ground a pixel is 0.16 m), with
// most matches where the true pose projects their points (points at a feature's rounded pixel's
// depth miss on slopes and edges).
void ExpectNearTruth(const Frame& frame, const Rigid3d& truth, const Map& map, double metres = 0.2,
                     double degrees = 0.2) {
  ASSERT_TRUE(frame.cam_from_world);
  EXPECT_LT(TranslationError(*frame.cam_from_world, truth), metres);
  EXPECT_LT(RotationErrorDeg(*frame.cam_from_world, truth), degrees);
  int matches = 0;
  EXPECT_GT(Strip().ConsistencyAt(frame, map, truth, 3.0, &matches), 0.85);
}

TEST(FramePlacer, MotionModelPlacesAFrameFromAConstantVelocity) {
  const OneKeyframe scene = MakeOneKeyframe(0);
  FramePlacer placer(TrackingOptions(), &Strip().geometry(), &DefaultVocabulary());
  Frame frame = Strip().Render(2);
  const Rigid3d truth = *frame.cam_from_world;
  // The prediction 0.6 m and 0.3 degrees off (a velocity that changed a little): the stage must
  // correct it.
  Rigid3d predicted = Strip().WorldFromCam(2);
  predicted.translation += Eigen::Vector3d(0.4, -0.4, 0.2);
  predicted.rotation =
      predicted.rotation * Eigen::Quaterniond(Eigen::AngleAxisd(0.3 * M_PI / 180, Eigen::Vector3d::UnitY()));
  const int inliers = placer.TrackWithMotionModel(scene.map, &frame, scene.last, predicted.Inverse());
  EXPECT_GT(inliers, 200);
  ExpectNearTruth(frame, truth, scene.map);
}

// An oblique camera (45 and 60 degrees from nadir, 40 m up, haze in the distance) sees the
// ground at a slant, so depth changes across the image: the renderer must stay consistent there
// and the motion model must hold as it does looking down (the quality gate's oblique cases).
TEST(FramePlacer, MotionModelPlacesObliqueViews) {
  for (const double pitch_deg : {45.0, 60.0}) {
    SCOPED_TRACE("camera pitch " + std::to_string(pitch_deg));
    SyntheticOptions options = RenderedViews::Strip(40);
    options.flight.camera_pitch_deg = pitch_deg;
    options.flight.altitude_m = 40;
    options.world.visibility_m = 600;
    RenderedViews views(options);
    cv::Mat depth;
    Frame last = views.Render(0, &depth);
    Keyframe keyframe;
    const Map map = views.MapFromFrame(last, depth, &keyframe);
    last.points = keyframe.points;
    FramePlacer placer(TrackingOptions(), &views.geometry(), &DefaultVocabulary());
    for (const int index : {1, 3, 6}) {
      Frame frame = views.Render(index);
      const Rigid3d truth = *frame.cam_from_world;
      Rigid3d predicted = views.WorldFromCam(index);  // 0.4 m off: the stage must correct it
      predicted.translation += Eigen::Vector3d(0.3, -0.2, 0.2);
      EXPECT_GT(placer.TrackWithMotionModel(map, &frame, last, predicted.Inverse()), 200) << "frame " << index;
      ASSERT_TRUE(frame.cam_from_world);
      EXPECT_LT(TranslationError(*frame.cam_from_world, truth), 0.2);
      EXPECT_LT(RotationErrorDeg(*frame.cam_from_world, truth), 0.2);
      int matches = 0;
      EXPECT_GT(views.ConsistencyAt(frame, map, truth, 3.0, &matches), 0.85);
    }
  }
}

TEST(FramePlacer, MotionModelRefusesAPredictionFarFromTheTruth) {
  const OneKeyframe scene = MakeOneKeyframe(0);
  FramePlacer placer(TrackingOptions(), &Strip().geometry(), &DefaultVocabulary());
  Frame frame = Strip().Render(2);
  // Predicted 30 m off to the side: the projections land on other features.
  Rigid3d wrong = Strip().WorldFromCam(2);
  wrong.translation += Eigen::Vector3d(0, 30, 0);
  EXPECT_EQ(placer.TrackWithMotionModel(scene.map, &frame, scene.last, wrong.Inverse()), 0);
}

TEST(FramePlacer, HomographyFollowsAFrameRolledTooFastForTheMotionModel) {
  const OneKeyframe scene = MakeOneKeyframe(0);
  FramePlacer placer(TrackingOptions(), &Strip().geometry(), &DefaultVocabulary());
  // Frame 2's position, rolled 25 degrees about the optical axis: the constant velocity (no
  // roll) predicts the features up to 140 px away from where they are.
  Rigid3d rolled = Strip().WorldFromCam(2);
  rolled.rotation =
      rolled.rotation * Eigen::Quaterniond(Eigen::AngleAxisd(25.0 * M_PI / 180.0, Eigen::Vector3d::UnitZ()));
  const Rigid3d truth = rolled.Inverse();
  const Rigid3d velocity = TrueVelocity(0, 1);
  Frame by_motion = Strip().RenderPose(rolled, 2);
  EXPECT_EQ(
      placer.TrackWithMotionModel(scene.map, &by_motion, scene.last, velocity * velocity * *scene.last.cam_from_world),
      0);
  Frame frame = Strip().RenderPose(rolled, 2);
  ASSERT_TRUE(placer.TrackWithHomography(scene.map, &frame, scene.last));
  ExpectNearTruth(frame, truth, scene.map);
}

TEST(FramePlacer, ReferenceKeyframePlacesAFrameWithoutAPose) {
  const OneKeyframe scene = MakeOneKeyframe(0);
  for (const char* matching : {"bow", "lsh", "brute_force"}) {
    TrackingOptions options;
    options.reference_matching = matching;
    FramePlacer placer(options, &Strip().geometry(), &DefaultVocabulary());
    Frame frame = Strip().Render(6);
    const Rigid3d truth = *frame.cam_from_world;
    frame.cam_from_world.reset();
    KeyframeId reference = scene.keyframe;
    ASSERT_TRUE(placer.TrackReferenceKeyframe(scene.map, &frame, nullptr, &reference)) << matching;
    ExpectNearTruth(frame, truth, scene.map);
    EXPECT_EQ(reference, scene.keyframe);
  }
}

TEST(FramePlacer, TheNewestKeyframeStandsInForACulledReference) {
  const OneKeyframe scene = MakeOneKeyframe(0);
  FramePlacer placer(TrackingOptions(), &Strip().geometry(), &DefaultVocabulary());
  Frame frame = Strip().Render(4);
  KeyframeId reference = MakeKeyframeId(scene.map.id(), 99);  // culled: not in the map
  EXPECT_TRUE(placer.TrackReferenceKeyframe(scene.map, &frame, &scene.last, &reference));
  EXPECT_EQ(reference, scene.keyframe);
}

// Keyframes at frames 0, 8 and 16 sharing points (each adds its new ones from depth).
struct ThreeKeyframes {
  Map map{MakeSubmapId(0, 1), ScalePyramid::From(OrbOptions())};
  std::vector<KeyframeId> keyframes;
};

const ThreeKeyframes& SharedThreeKeyframes() {
  static const ThreeKeyframes* scene = [] {
    auto* s = new ThreeKeyframes;
    for (int i = 0; i < 3; ++i) {
      cv::Mat depth;
      Frame frame = Strip().Render(8 * i, &depth);
      s->keyframes.push_back(Strip().AddKeyframe(&s->map, frame, depth, i));
      Keyframe* kf = s->map.FindKeyframe(s->keyframes.back());
      kf->bow = DefaultVocabulary().Transform(kf->descriptors, &kf->bow_features);
    }
    return s;
  }();
  return *scene;
}

TEST(FramePlacer, LocalMapSearchFindsThePointsOfTheCovisibleKeyframes) {
  const ThreeKeyframes& scene = SharedThreeKeyframes();
  FramePlacer placer(TrackingOptions(), &Strip().geometry(), &DefaultVocabulary());
  Frame frame = Strip().Render(20);
  const Rigid3d truth = *frame.cam_from_world;
  // 40 points of the first keyframe matched (as a weak frame-to-frame step leaves it), the pose
  // a little off.
  const Keyframe& first = *scene.map.FindKeyframe(scene.keyframes[0]);
  std::vector<PointInView> in_view;
  for (MapPointId p : first.points) {
    PointInView view;
    if (p.valid() && Strip().geometry().InView(*scene.map.FindPoint(p), truth, &view)) in_view.push_back(view);
  }
  SearchByProjection(&frame, in_view, scene.map, 1.0);
  int kept = 0;
  for (MapPointId& p : frame.points) {
    if (p.valid() && ++kept > 40) p = MapPointId();
  }
  ASSERT_EQ(frame.CountTracked(), 40);
  Rigid3d start = truth;
  start.translation += Eigen::Vector3d(0.05, -0.05, 0.02);
  frame.cam_from_world = start;
  KeyframeId reference;
  ASSERT_TRUE(placer.TrackLocalMap(scene.map, &frame, 50, &reference));
  EXPECT_GT(frame.CountTracked(), 300) << "points of all three keyframes";
  ExpectNearTruth(frame, truth, scene.map);
  EXPECT_TRUE(reference.valid());
  // Too few points confirmed: not tracked.
  Frame weak = Strip().Render(20);
  weak.cam_from_world = truth;
  KeyframeId unused;
  EXPECT_FALSE(placer.TrackLocalMap(scene.map, &weak, 5000, &unused));
}

TEST(FramePlacer, PlacesInTheStatedOrder) {
  const OneKeyframe scene = MakeOneKeyframe(0);
  FramePlacer placer(TrackingOptions(), &Strip().geometry(), &DefaultVocabulary());
  const auto place = [&](const Frame* last, const std::optional<Rigid3d>& velocity) {
    Frame frame = Strip().Render(1);
    const Rigid3d truth = *frame.cam_from_world;
    KeyframeId reference = scene.keyframe;
    const FramePlacer::Placement placement = placer.Place(&frame, scene.map, last, velocity, 30, &reference);
    EXPECT_TRUE(placement.tracked);
    ExpectNearTruth(frame, truth, scene.map);
    return std::string(placement.tracked_by);
  };
  EXPECT_EQ(place(&scene.last, TrueVelocity(0, 1)), "motion model");
  EXPECT_EQ(place(&scene.last, std::nullopt), "homography");
  EXPECT_EQ(place(nullptr, std::nullopt), "reference keyframe");
}

// ---------------------------------------------------------------- keyframe decision

TEST(KeyframeDecision, AKeyframeWhenTheFrameTracksFewOfItsReferencesPoints) {
  const TrackingOptions options;  // keyframe_ratio 0.9; parallax not measured here
  KeyframeDecisionInput input;
  input.reference_points = 300;
  input.frames_since_keyframe = 5;
  input.tracked_points = 290;
  EXPECT_FALSE(NeedKeyframe(input, options, 20)) << "tracks nearly all";
  input.tracked_points = 250;
  EXPECT_TRUE(NeedKeyframe(input, options, 20));
  input.tracked_points = 15;
  EXPECT_FALSE(NeedKeyframe(input, options, 20)) << "too few points to make a keyframe of";
  input.tracked_points = 250;
  input.mapper_ready = false;
  EXPECT_FALSE(NeedKeyframe(input, options, 20)) << "the mapper has not taken the last one";
  input.frames_since_keyframe = 100;
  EXPECT_FALSE(NeedKeyframe(input, options, 20)) << "a long gap does not overrule a busy mapper";
  input.has_reference = false;
  EXPECT_TRUE(NeedKeyframe(input, options, 20)) << "a culled reference always gives a keyframe";
}

// A tracker that does not wait for its mapper (live frames) makes a keyframe only while fewer
// than keyframes_in_flight of those it sent are unanswered; an answer lets it go on.
TEST(KeyframeDecision, KeyframesWaitWhileKeyframesInFlightAreUnanswered) {
  const auto keyframes_made = [](int in_flight, int answer_after) {
    TrackingOptions options;
    options.keyframes_in_flight = in_flight;
    Tracking tracking(options, Strip().sequence().camera(), &testing::DefaultVocabulary(), 20);
    int made = 0;
    // Frames 0-14: without its mapper's points the tracker loses the strip at frame 15.
    for (int i = 0; i < 15; ++i) {
      const cv::Mat image = Strip().sequence().RenderFrame(i);
      Tracking::Output output = tracking.Track(image, i, Strip().sequence().flight().TimestampNs(i));
      for (const Keyframe& keyframe : output.new_keyframes) {
        if (++made == answer_after) {  // the mapper answers this one (and those before it)
          LocalMapUpdate answer;
          answer.submap = SubmapOf(keyframe.id);
          answer.last_keyframe = keyframe.id;
          tracking.ApplyUpdate(answer);
        }
      }
    }
    EXPECT_TRUE(tracking.mapper_connected());
    return made;
  };
  // Initialization sends two keyframes at once; nobody answers.
  EXPECT_EQ(keyframes_made(3, -1), 3);
  EXPECT_EQ(keyframes_made(4, -1), 4);
  // The answer to the third frees three more places.
  EXPECT_EQ(keyframes_made(3, 3), 6);
}

// A live tracker on a thin map waits for the newest keyframe's points (tracker service,
// live_wait_for_points_s): they have come with the mapper's early update (its associations name
// the keyframe) or its whole answer, not with an update about older keyframes.
TEST(KeyframeDecision, TheNewestKeyframesPointsComeWithAnUpdateNamingIt) {
  Tracking tracking(TrackingOptions(), Strip().sequence().camera(), &testing::DefaultVocabulary(), 20);
  EXPECT_TRUE(tracking.NewestKeyframePointsReceived()) << "no keyframe sent yet";
  std::vector<Keyframe> sent;
  for (int i = 0; i < 15 && sent.empty(); ++i) {
    Tracking::Output output =
        tracking.Track(Strip().sequence().RenderFrame(i), i, Strip().sequence().flight().TimestampNs(i));
    for (Keyframe& keyframe : output.new_keyframes) sent.push_back(std::move(keyframe));
  }
  ASSERT_EQ(sent.size(), 2u) << "initialization's two keyframes";
  const Keyframe& newest = sent.back();
  ASSERT_EQ(tracking.last_keyframe_sent(), newest.id);
  EXPECT_FALSE(tracking.NewestKeyframePointsReceived());
  LocalMapUpdate older;
  older.submap = SubmapOf(newest.id);
  older.revision = 1;
  older.associations.push_back({sent[0].id, sent[0].points});
  tracking.ApplyUpdate(older, false);
  EXPECT_FALSE(tracking.NewestKeyframePointsReceived()) << "an update about an older keyframe";
  LocalMapUpdate early = older;  // MakeNewPointsUpdate's shape: associations, no last_keyframe
  early.revision = 2;
  early.associations.push_back({newest.id, newest.points});
  tracking.ApplyUpdate(early, false);
  EXPECT_TRUE(tracking.NewestKeyframePointsReceived());
  EXPECT_EQ(tracking.KeyframesInFlight(), static_cast<int>(sent.size())) << "its whole answer has not come";
}

TEST(KeyframeDecision, ReferencePointsCountPointsSeenOften) {
  const ThreeKeyframes& scene = SharedThreeKeyframes();
  const Keyframe& middle = *scene.map.FindKeyframe(scene.keyframes[1]);
  int seen_three_times = 0;
  for (MapPointId p : middle.points) {
    const MapPoint* point = p.valid() ? scene.map.FindPoint(p) : nullptr;
    seen_three_times += point && point->observations.size() >= 3;
  }
  EXPECT_GT(seen_three_times, 50);
  EXPECT_EQ(ReferencePoints(scene.map, middle), seen_three_times);
}

TEST(KeyframeDecision, LittleParallaxNeedsMuchNewGround) {
  TrackingOptions options;
  options.keyframe_min_parallax_deg = 2;
  options.keyframe_ratio_without_parallax = 0.6;
  options.keyframe_gap_without_parallax_s = 0;  // the ratio alone
  KeyframeDecisionInput input;
  input.reference_points = 300;
  input.frames_since_keyframe = 5;
  input.tracked_points = 250;  // under 0.9 x 300
  input.parallax_deg = 5;
  EXPECT_TRUE(NeedKeyframe(input, options, 20)) << "moved enough to triangulate";
  input.parallax_deg = 0.5;
  EXPECT_FALSE(NeedKeyframe(input, options, 20)) << "a rotation that still sees most of the reference";
  input.tracked_points = 150;  // under 0.6 x 300: much new ground
  EXPECT_TRUE(NeedKeyframe(input, options, 20));
  input.tracked_points = 250;
  input.parallax_deg = -1;
  EXPECT_TRUE(NeedKeyframe(input, options, 20)) << "not measured: the plain ratio";
  options.keyframe_min_parallax_deg = 0;
  input.parallax_deg = 0.5;
  EXPECT_TRUE(NeedKeyframe(input, options, 20)) << "off";
}

TEST(KeyframeDecision, LittleParallaxMakesKeyframesAtTheMappersPace) {
  TrackingOptions options;
  options.keyframe_min_parallax_deg = 1;
  options.keyframe_ratio_without_parallax = 0.5;
  options.keyframe_gap_without_parallax_s = 0.2;  // 6 frames at 30 fps, 2 at 10 fps
  KeyframeDecisionInput input;
  input.reference_points = 300;
  input.tracked_points = 250;  // under 0.9 x 300, over 0.5 x 300
  input.parallax_deg = 0.3;
  input.frames_since_keyframe = 3;
  EXPECT_FALSE(NeedKeyframe(input, options, 30)) << "a rotation, 0.1 s after the last keyframe";
  EXPECT_TRUE(NeedKeyframe(input, options, 10)) << "0.3 s after it";
  input.frames_since_keyframe = 6;
  EXPECT_TRUE(NeedKeyframe(input, options, 30)) << "0.2 s after it";
  input.frames_since_keyframe = 1;
  input.tracked_points = 140;  // under 0.5 x 300: much new ground
  EXPECT_TRUE(NeedKeyframe(input, options, 30));
  input.tracked_points = 250;
  input.parallax_deg = 1.5;
  EXPECT_TRUE(NeedKeyframe(input, options, 30)) << "moved enough to triangulate: no pace";
  input.parallax_deg = 0.3;
  input.mapper_ready = false;
  input.frames_since_keyframe = 30;
  EXPECT_FALSE(NeedKeyframe(input, options, 30)) << "the pace does not overrule a busy mapper";
  options.keyframe_min_parallax_deg = 0;
  input.mapper_ready = true;
  input.frames_since_keyframe = 1;
  EXPECT_TRUE(NeedKeyframe(input, options, 30)) << "off: the plain ratio";
}

TEST(KeyframeDecision, ParallaxIsTheAngleTheCamerasMotionOpensAtThePoints) {
  const OneKeyframe scene = MakeOneKeyframe(0);
  const Keyframe& reference = *scene.map.FindKeyframe(scene.keyframe);
  Frame frame = scene.last;  // tracks every point of the keyframe
  // The same place: no parallax; turned in place: still none.
  EXPECT_NEAR(MedianParallaxDeg(scene.map, reference, frame), 0, 1e-6);
  const Eigen::Quaterniond turn(Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitX()));
  frame.cam_from_world = Rigid3d(turn, Eigen::Vector3d::Zero()) * *frame.cam_from_world;  // the same centre
  EXPECT_NEAR(MedianParallaxDeg(scene.map, reference, frame), 0, 1e-6);
  // Moved 7 m sideways about 70 m above the ground: about atan(7 / 70) = 5.7 degrees.
  Rigid3d world_from_cam = reference.cam_from_world.Inverse();
  world_from_cam.translation += Eigen::Vector3d(0, 7, 0);
  frame.cam_from_world = world_from_cam.Inverse();
  EXPECT_NEAR(MedianParallaxDeg(scene.map, reference, frame), 5.7, 1.0);
  frame.points.assign(frame.points.size(), MapPointId());
  EXPECT_EQ(MedianParallaxDeg(scene.map, reference, frame), -1) << "no point tracked";
}

TEST(KeyframeDecision, MotionAxisAngleIsBetweenTheOpticalAxisAndTheMotionSinceTheReference) {
  // A camera at the origin looking along world x (its z axis), then moved.
  Keyframe reference;
  const Eigen::Matrix3d world_from_cam_rotation =
      (Eigen::Matrix3d() << 0, 0, 1, -1, 0, 0, 0, -1, 0).finished();  // columns: cam x, y, z in the world
  const Rigid3d world_from_reference(Eigen::Quaterniond(world_from_cam_rotation), Eigen::Vector3d::Zero());
  reference.cam_from_world = world_from_reference.Inverse();
  Frame frame;
  const auto moved_to = [&](const Eigen::Vector3d& centre) {
    frame.cam_from_world = Rigid3d(world_from_reference.rotation, centre).Inverse();
    return MotionAxisAngleDeg(reference, frame);
  };
  EXPECT_NEAR(moved_to({2, 0, 0}), 0, 1e-9) << "straight ahead";
  EXPECT_NEAR(moved_to({-2, 0, 0}), 0, 1e-9) << "straight back";
  EXPECT_NEAR(moved_to({0, 3, 0}), 90, 1e-9) << "sideways";
  EXPECT_NEAR(moved_to({1, 0, -1}), 45, 1e-9) << "ahead and down";
  EXPECT_EQ(moved_to({0, 0, 0}), -1) << "not moved";
  frame.cam_from_world.reset();
  EXPECT_EQ(MotionAxisAngleDeg(reference, frame), -1) << "not posed";
}

TEST(KeyframeDecision, ACameraMovingAlongItsViewingDirectionKeepsMoreOfItsPoints) {
  TrackingOptions options;
  options.keyframe_ratio = 0.9;
  options.keyframe_ratio_along_axis = 0.95;
  options.keyframe_along_axis_max_angle_deg = 25;
  KeyframeDecisionInput input;
  input.reference_points = 300;
  input.frames_since_keyframe = 5;
  input.tracked_points = 280;  // 0.93 of the reference's
  input.parallax_deg = 3;
  input.motion_axis_angle_deg = 90;
  EXPECT_FALSE(NeedKeyframe(input, options, 20)) << "a downward camera flying level: the ratio is 0.9";
  EXPECT_DOUBLE_EQ(KeyframeRatio(input, options), 0.9);
  input.motion_axis_angle_deg = 10;
  EXPECT_TRUE(NeedKeyframe(input, options, 20)) << "a forward camera: the ratio is 0.95";
  EXPECT_DOUBLE_EQ(KeyframeRatio(input, options), 0.95);
  input.motion_axis_angle_deg = 30;
  EXPECT_FALSE(NeedKeyframe(input, options, 20)) << "beyond the angle";
  input.motion_axis_angle_deg = -1;
  EXPECT_FALSE(NeedKeyframe(input, options, 20)) << "not measured";
  input.motion_axis_angle_deg = 10;
  input.parallax_deg = 0.5;
  EXPECT_FALSE(NeedKeyframe(input, options, 20)) << "too little parallax: a rotating camera keeps 0.9";
  input.parallax_deg = 3;
  input.tracked_points = 290;
  EXPECT_FALSE(NeedKeyframe(input, options, 20)) << "tracks nearly all";
}

// A 640x480 frame with 4 features in every cell of the 8x6 grid TrackedCoverage uses (80x80
// pixels), the first of them tracked in the cells left of column `tracked_columns`.
Frame FrameWithFeaturesInEveryCell(int tracked_columns) {
  Frame frame;
  for (int row = 0; row < 6; ++row) {
    for (int col = 0; col < 8; ++col) {
      for (int k = 0; k < 4; ++k) {
        frame.keypoints.emplace_back(cv::Point2f(80.f * col + 10.f + 15.f * k, 80.f * row + 40.f), 31.f);
        const bool tracked = col < tracked_columns && k == 0;
        frame.points.push_back(tracked ? MakeMapPointId(MakeSubmapId(0, 1), frame.keypoints.size()) : MapPointId());
        frame.outlier.push_back(0);
      }
    }
  }
  return frame;
}

TEST(KeyframeDecision, CoverageIsTheShareOfFeatureCellsWhereAMapPointIsTracked) {
  EXPECT_DOUBLE_EQ(TrackedCoverage(FrameWithFeaturesInEveryCell(8), 640, 480), 1.0);
  EXPECT_DOUBLE_EQ(TrackedCoverage(FrameWithFeaturesInEveryCell(4), 640, 480), 0.5);
  EXPECT_DOUBLE_EQ(TrackedCoverage(FrameWithFeaturesInEveryCell(0), 640, 480), 0.0);
  // An outlier is no tracked point.
  Frame outliers = FrameWithFeaturesInEveryCell(8);
  outliers.outlier.assign(outliers.size(), 1);
  EXPECT_DOUBLE_EQ(TrackedCoverage(outliers, 640, 480), 0.0);
  // Cells with fewer than 3 features do not count either way: the right half without features.
  Frame half = FrameWithFeaturesInEveryCell(4);
  for (size_t i = 0; i < half.size(); ++i) {
    if (half.keypoints[i].pt.x >= 320) half.keypoints[i].pt.x = 5;  // all into column 0 instead
  }
  EXPECT_DOUBLE_EQ(TrackedCoverage(half, 640, 480), 1.0);
  EXPECT_EQ(TrackedCoverage(Frame(), 640, 480), -1) << "no feature";
}

TEST(KeyframeDecision, NewGroundInViewMakesAKeyframeWhereTheCameraMovedEnoughToMapIt) {
  TrackingOptions options;
  options.keyframe_min_coverage = 0.8;  // with keyframe_coverage_min_parallax_deg 2
  KeyframeDecisionInput input;
  input.reference_points = 300;
  input.frames_since_keyframe = 5;
  input.tracked_points = 290;  // the ratio alone: no keyframe
  input.tracked_coverage = 0.5;
  input.parallax_deg = 5;
  EXPECT_TRUE(NeedKeyframe(input, options, 20)) << "half the view is new ground, seen with parallax";
  input.parallax_deg = 0.5;
  EXPECT_FALSE(NeedKeyframe(input, options, 20)) << "a turning camera cannot triangulate the new ground";
  input.parallax_deg = 5;
  input.tracked_coverage = 0.9;
  EXPECT_FALSE(NeedKeyframe(input, options, 20)) << "the map covers the view";
  input.tracked_coverage = 0.5;
  input.mapper_ready = false;
  EXPECT_FALSE(NeedKeyframe(input, options, 20)) << "the mapper has not taken the last one";
  input.mapper_ready = true;
  input.tracked_points = 15;
  EXPECT_FALSE(NeedKeyframe(input, options, 20)) << "too few points to make a keyframe of";
  TrackingOptions off = options;
  off.keyframe_min_coverage = 0;
  input.tracked_points = 290;
  EXPECT_FALSE(NeedKeyframe(input, off, 20)) << "off";
}

// ---------------------------------------------------------------- relocalization

// A store whose current (or, with `close`, closed) submap holds SharedThreeKeyframes.
std::unique_ptr<SubmapStore> StoreWithThreeKeyframes(bool close) {
  auto store = std::make_unique<SubmapStore>();
  store->StartCurrent(std::make_unique<Map>(SharedThreeKeyframes().map), 3);
  for (KeyframeId id : SharedThreeKeyframes().keyframes) store->AddToDatabase(*store->current()->FindKeyframe(id));
  if (close) store->CloseCurrent();
  return store;
}

TEST(Relocalizer, PlacesAFrameInTheSubmapItSees) {
  auto store = StoreWithThreeKeyframes(/*close=*/false);
  FramePlacer placer(TrackingOptions(), &Strip().geometry(), &DefaultVocabulary());
  Relocalizer relocalizer(TrackingOptions(), &placer, &DefaultVocabulary());
  Frame frame = Strip().Render(24);
  const Rigid3d truth = *frame.cam_from_world;
  frame.cam_from_world.reset();
  KeyframeId reference;
  const std::optional<KeyframeId> at =
      relocalizer.Relocalize(&frame, store.get(), &reference, RelocalizationScope::kCurrentSubmap);
  ASSERT_TRUE(at);
  EXPECT_EQ(SubmapOf(*at), store->current()->id());
  EXPECT_TRUE(reference.valid());
  EXPECT_GE(frame.CountTracked(), TrackingOptions().relocalization_min_inliers);
  ExpectNearTruth(frame, truth, *store->current());
}

TEST(Relocalizer, FindsAClosedSubmapWhenThereIsNoCurrentOne) {
  auto store = StoreWithThreeKeyframes(/*close=*/true);
  ASSERT_EQ(store->current(), nullptr);
  FramePlacer placer(TrackingOptions(), &Strip().geometry(), &DefaultVocabulary());
  Relocalizer relocalizer(TrackingOptions(), &placer, &DefaultVocabulary());
  Frame frame = Strip().Render(12);
  KeyframeId reference;
  const std::optional<KeyframeId> at =
      relocalizer.Relocalize(&frame, store.get(), &reference, RelocalizationScope::kClosedSubmaps);
  ASSERT_TRUE(at);
  EXPECT_EQ(SubmapOf(*at), SharedThreeKeyframes().map.id());
  // There is no current submap to relocalize in.
  Frame again = Strip().Render(12);
  EXPECT_FALSE(relocalizer.Relocalize(&again, store.get(), &reference, RelocalizationScope::kCurrentSubmap));
}

TEST(Relocalizer, TheClosedScopeLeavesTheCurrentSubmapOut) {
  // A young submap's frame that would relocalize in the young submap itself is no way back.
  auto store = StoreWithThreeKeyframes(/*close=*/false);
  FramePlacer placer(TrackingOptions(), &Strip().geometry(), &DefaultVocabulary());
  Relocalizer relocalizer(TrackingOptions(), &placer, &DefaultVocabulary());
  Frame frame = Strip().Render(12);
  KeyframeId reference;
  EXPECT_FALSE(relocalizer.Relocalize(&frame, store.get(), &reference, RelocalizationScope::kClosedSubmaps));
}

TEST(Relocalizer, LandsOnlyAtTheKeyframesItIsGiven) {
  // Resuming where the camera was lost: only the local map it was lost from may take the frame.
  auto store = StoreWithThreeKeyframes(/*close=*/true);
  FramePlacer placer(TrackingOptions(), &Strip().geometry(), &DefaultVocabulary());
  Relocalizer relocalizer(TrackingOptions(), &placer, &DefaultVocabulary());
  const std::vector<KeyframeId>& keyframes = SharedThreeKeyframes().keyframes;
  const std::set<KeyframeId> elsewhere = {MakeKeyframeId(SharedThreeKeyframes().map.id(), 999)};
  KeyframeId reference;
  Frame frame = Strip().Render(12);
  EXPECT_FALSE(
      relocalizer.Relocalize(&frame, store.get(), &reference, RelocalizationScope::kClosedSubmaps, 0, &elsewhere));
  const std::set<KeyframeId> local(keyframes.begin(), keyframes.end());
  frame = Strip().Render(12);
  const std::optional<KeyframeId> at =
      relocalizer.Relocalize(&frame, store.get(), &reference, RelocalizationScope::kClosedSubmaps, 0, &local);
  ASSERT_TRUE(at);
  EXPECT_TRUE(local.count(*at));
}

TEST(Relocalizer, NeedsTheLocalMapToConfirmThePose) {
  auto store = StoreWithThreeKeyframes(/*close=*/false);
  TrackingOptions options;
  options.relocalization_min_inliers = 5000;  // more points than the local map holds
  FramePlacer placer(options, &Strip().geometry(), &DefaultVocabulary());
  Relocalizer relocalizer(options, &placer, &DefaultVocabulary());
  Frame frame = Strip().Render(24);
  KeyframeId reference;
  EXPECT_FALSE(relocalizer.Relocalize(&frame, store.get(), &reference, RelocalizationScope::kCurrentSubmap));
}

TEST(Relocalizer, RefusesAFrameOfAPlaceTheSubmapNeverSaw) {
  auto store = StoreWithThreeKeyframes(/*close=*/false);
  FramePlacer placer(TrackingOptions(), &Strip().geometry(), &DefaultVocabulary());
  Relocalizer relocalizer(TrackingOptions(), &placer, &DefaultVocabulary());
  Frame frame = Strip().Render(190);  // 170 m further along: no overlap
  KeyframeId reference;
  EXPECT_FALSE(relocalizer.Relocalize(&frame, store.get(), &reference, RelocalizationScope::kCurrentSubmap));
}

// ---------------------------------------------------------------- the store of submaps

TEST(SubmapStore, ClosesReopensAndKeepsEachSubmapsNumbering) {
  SubmapStore store;
  const SubmapId first = MakeSubmapId(0, 1), second = MakeSubmapId(0, 2);
  store.StartCurrent(std::make_unique<Map>(first, ScalePyramid()), 2);
  EXPECT_EQ(store.NewKeyframeId(), MakeKeyframeId(first, 2));
  EXPECT_EQ(store.CloseCurrent(), first);
  EXPECT_EQ(store.current(), nullptr);
  EXPECT_TRUE(store.has_closed());
  store.StartCurrent(std::make_unique<Map>(second, ScalePyramid()), 0);
  EXPECT_EQ(store.NewKeyframeId(), MakeKeyframeId(second, 0));
  ASSERT_TRUE(store.Reopen(first));  // the current one is closed on the way
  EXPECT_EQ(store.current()->id(), first);
  EXPECT_EQ(store.NewKeyframeId(), MakeKeyframeId(first, 3)) << "numbering goes on";
  EXPECT_NE(store.FindMap(second), nullptr);
  EXPECT_FALSE(store.Reopen(MakeSubmapId(0, 7)));
}

TEST(SubmapStore, AppliesTheMappersUpdateToAClosedSubmapAndForgetsRemovedKeyframes) {
  auto store = StoreWithThreeKeyframes(/*close=*/true);
  const KeyframeId removed = SharedThreeKeyframes().keyframes[1];
  ASSERT_TRUE(store->database().Contains(removed.value));
  LocalMapUpdate update;
  update.submap = SharedThreeKeyframes().map.id();
  update.removed_keyframes = {removed};
  EXPECT_TRUE(store->Apply(update));
  EXPECT_EQ(store->FindKeyframe(removed), nullptr);
  EXPECT_FALSE(store->database().Contains(removed.value));
  update.submap = MakeSubmapId(3, 3);
  EXPECT_FALSE(store->Apply(update)) << "a submap it does not hold";
}

}  // namespace
}  // namespace stitch
