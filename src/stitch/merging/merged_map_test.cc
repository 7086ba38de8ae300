#include "stitch/merging/merged_map.h"

#include <algorithm>
#include <cstdio>

#include <gtest/gtest.h>

#include "stitch/geometry/similarity.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

const Camera kCamera = Camera::Pinhole(640, 480, 450, 450, 319.5, 239.5);
const SubmapId kA = MakeSubmapId(0, 1), kB = MakeSubmapId(0, 2);
constexpr int kKeyframesPerSubmap = 6;
constexpr int kPoints = 300;

// One scene seen by two submaps: A flies x = 0..2.5 in the world frame, B flies x = 3..5.5 in a
// frame of its own (scale 0.5, rotated, shifted), both seeing every point, each through map
// points of its own. Observations are exact, so the merged map can be checked to the truth.
struct TwoSubmaps {
  std::map<SubmapId, SubmapReplica> submaps;
  Sim3d b_from_world{0.5, Eigen::Quaterniond(Eigen::AngleAxisd(0.35, Eigen::Vector3d(0.2, 1, 0.3).normalized())),
                     Eigen::Vector3d(1, -2, 3)};
  std::vector<Eigen::Vector3d> points;                         // world
  std::map<KeyframeId, Eigen::Vector3d> centres;               // world
  std::vector<std::pair<MapPointId, MapPointId>> same_points;  // (in A, in B)
};

TwoSubmaps MakeTwoSubmaps() {
  TwoSubmaps scene;
  Rng rng(11);
  const ScalePyramid pyramid = ScalePyramid::From(OrbOptions());
  const Undistorter undistorter(kCamera);
  std::vector<cv::Mat> descriptors;
  for (int p = 0; p < kPoints; ++p) {
    scene.points.emplace_back(rng.Uniform(0.5, 5), rng.Uniform(-3, 3), rng.Uniform(9, 12));
    cv::Mat d(1, 32, CV_8U);
    for (int b = 0; b < 32; ++b) d.at<uint8_t>(0, b) = static_cast<uint8_t>(rng.UniformInt(0, 255));
    descriptors.push_back(d);
  }
  for (const SubmapId submap : {kA, kB}) {
    const Sim3d frame_from_world = submap == kA ? Sim3d() : scene.b_from_world;
    SubmapReplica replica(submap, pyramid);
    replica.camera = kCamera;
    for (int p = 0; p < kPoints; ++p) {
      MapPoint point;
      point.id = MakeMapPointId(submap, static_cast<uint32_t>(p));
      point.position = frame_from_world * scene.points[p];
      descriptors[p].row(0).copyTo(cv::Mat(1, 32, CV_8U, point.descriptor.data()));
      replica.map.AddPoint(point);
    }
    for (int k = 0; k < kKeyframesPerSubmap; ++k) {
      const double x = (submap == kA ? 0.0 : 3.0) + 0.5 * k;
      const Rigid3d world_from_cam(Eigen::Quaterniond(Eigen::AngleAxisd(0.03 * k - 0.05, Eigen::Vector3d::UnitY())),
                                   Eigen::Vector3d(x, 0.1 * k, 0));
      Keyframe keyframe;
      keyframe.id = MakeKeyframeId(submap, k);
      scene.centres[keyframe.id] = world_from_cam.translation;
      const Sim3d frame_from_cam = frame_from_world * Sim3d(1, world_from_cam.rotation, world_from_cam.translation);
      keyframe.cam_from_world = Rigid3d(frame_from_cam.rotation, frame_from_cam.translation).Inverse();
      keyframe.descriptors = cv::Mat(kPoints, 32, CV_8U);
      for (int p = 0; p < kPoints; ++p) {
        const Eigen::Vector2d pixel = kCamera.Intrinsics().Project(world_from_cam.Inverse() * scene.points[p]);
        cv::KeyPoint keypoint(static_cast<float>(pixel.x()), static_cast<float>(pixel.y()), 31);
        keypoint.octave = 2;
        keyframe.keypoints.push_back(keypoint);
        keyframe.undistorted.push_back(pixel);
        keyframe.points.push_back(MakeMapPointId(submap, static_cast<uint32_t>(p)));
        descriptors[p].copyTo(keyframe.descriptors.row(p));
      }
      keyframe.grid = FeatureGrid(keyframe.undistorted, undistorter);
      replica.map.AddKeyframe(keyframe);
    }
    for (int p = 0; p < kPoints; ++p) replica.map.UpdatePointGeometry(MakeMapPointId(submap, static_cast<uint32_t>(p)));
    for (int k = 0; k < kKeyframesPerSubmap; ++k) replica.map.UpdateConnections(MakeKeyframeId(submap, k));
    scene.submaps.emplace(submap, std::move(replica));
  }
  for (int p = 0; p < kPoints; ++p) {
    scene.same_points.push_back(
        {MakeMapPointId(kA, static_cast<uint32_t>(p)), MakeMapPointId(kB, static_cast<uint32_t>(p))});
  }
  return scene;
}

// A in its own frame; B placed by the true similarity made slightly wrong.
std::map<SubmapId, SubmapPlacement> Placement(const TwoSubmaps& scene, const Sim3d& error) {
  std::map<SubmapId, SubmapPlacement> placement;
  placement[kA] = {0, kA, Sim3d(), kA};
  placement[kB] = {0, kA, error * scene.b_from_world.Inverse(), kA};
  return placement;
}

// The worst distance between a merged keyframe centre and the truth, after a similarity
// alignment of all of them (monocular bundle adjustment keeps its scale gauge free).
double WorstCentreError(const MergedMap& merged, const TwoSubmaps& scene) {
  std::vector<Eigen::Vector3d> estimated, truth;
  for (const auto& [id, pose] : merged.keyframe_poses) {
    estimated.push_back(pose.translation);
    truth.push_back(scene.centres.at(id));
  }
  const Sim3d truth_from_estimated = AlignPoints(estimated, truth);
  double worst = 0;
  for (size_t i = 0; i < estimated.size(); ++i)
    worst = std::max(worst, (truth_from_estimated * estimated[i] - truth[i]).norm());
  return worst;
}

// B placed 1.5 degrees and 10 cm off, as an edge Sim3 from a few points can be.
const Sim3d kMisplacement(1.0, Eigen::Quaterniond(Eigen::AngleAxisd(1.5 * M_PI / 180, Eigen::Vector3d::UnitX())),
                          Eigen::Vector3d(0.1, 0, 0));

// A's keyframe 5 and B's keyframe 0 connected by only 40 verified matches (the rest of the overlap
// must be found by projection).
ConnectedFrame FewMatches(const TwoSubmaps& scene) {
  ConnectedFrame connection;
  connection.keyframe_a = MakeKeyframeId(kA, 5);
  connection.keyframe_b = MakeKeyframeId(kB, 0);
  connection.point_pairs.assign(scene.same_points.begin(), scene.same_points.begin() + 40);
  return connection;
}

// The two submaps merged along `connection`, B placed by the true similarity made wrong by `error`.
MergedMap AssembleAlong(const TwoSubmaps& scene, const Sim3d& error, const ConnectedFrame& connection,
                        const MergedMapOptions& options = MergedMapOptions()) {
  return AssembleMergedMap(scene.submaps, Placement(scene, error), {}, {connection}, 0,
                           ScalePyramid::From(OrbOptions()), kCamera.Intrinsics(), options);
}

MergedMap AssembleMisplaced(const TwoSubmaps& scene, const MergedMapOptions& options) {
  return AssembleAlong(scene, kMisplacement, FewMatches(scene), options);
}

TEST(MergedMap, FusedPointsLetTheBundleAdjustmentPutAMisplacedSubmapBack) {
  const TwoSubmaps scene = MakeTwoSubmaps();
  MergedMapOptions unadjusted;
  unadjusted.fuse_points = false;
  unadjusted.bundle_adjustment = false;
  const MergedMap placed = AssembleMisplaced(scene, unadjusted);
  EXPECT_EQ(placed.map.num_points(), 2u * kPoints);
  EXPECT_EQ(placed.map.num_keyframes(), 2u * kKeyframesPerSubmap);
  EXPECT_GT(WorstCentreError(placed, scene), 0.03);

  const MergedMap merged = AssembleMisplaced(scene, MergedMapOptions());
  EXPECT_EQ(merged.points_fused_by_connection, 40);
  EXPECT_GT(merged.points_fused_by_projection, 200);
  EXPECT_LT(merged.map.num_points(), 2u * kPoints - 240);
  EXPECT_GT(merged.bundle_adjustment.initial_rms_px, 1.0);
  EXPECT_LT(merged.bundle_adjustment.final_rms_px, 0.01);
  EXPECT_LT(WorstCentreError(merged, scene), 1e-3);
  // Keyframes keep their submap's scale: B's are twice A's (B's frame has scale 0.5).
  EXPECT_NEAR(merged.keyframe_poses.at(MakeKeyframeId(kB, 3)).scale, 2.0, 1e-9);
  EXPECT_NEAR(merged.keyframe_poses.at(MakeKeyframeId(kA, 3)).scale, 1.0, 1e-9);
}

TEST(MergedMap, ALongFlightsAdjustmentMovesOnlyTheNewestKeyframes) {
  const TwoSubmaps scene = MakeTwoSubmaps();
  MergedMapOptions unadjusted;
  unadjusted.bundle_adjustment = false;
  const MergedMap placed = AssembleMisplaced(scene, unadjusted);
  MergedMapOptions capped;
  capped.bundle_adjustment_max_free_keyframes = 4;
  const MergedMap merged = AssembleMisplaced(scene, capped);
  EXPECT_EQ(merged.bundle_adjustment.keyframes_free, 4);
  EXPECT_LE(merged.bundle_adjustment.final_rms_px, merged.bundle_adjustment.initial_rms_px);
  // Only the newest four (same time stamps here: the highest ids) were free; every other stayed put.
  std::vector<KeyframeId> ids;
  for (const auto& [id, keyframe] : merged.map.keyframes()) ids.push_back(id);
  std::sort(ids.rbegin(), ids.rend());
  for (size_t i = 4; i < ids.size(); ++i) {
    EXPECT_LT((merged.map.FindKeyframe(ids[i])->Centre() - placed.map.FindKeyframe(ids[i])->Centre()).norm(), 1e-12)
        << ids[i];
  }
}

SubmapEdge TreeEdge() {
  SubmapEdge edge;
  edge.a = kA;
  edge.b = kB;
  edge.connected_frames = 2;
  return edge;
}

TEST(MergedMap, AJunctionTheAdjustmentHoldsPassesTheCheckAfterPlacement) {
  const TwoSubmaps scene = MakeTwoSubmaps();
  const MergedMap merged = AssembleMisplaced(scene, MergedMapOptions());
  ASSERT_EQ(merged.junctions.size(), 1u);
  const Junction& junction = merged.junctions.at(SubmapPair(kB, kA));
  // Each fused point joins six keyframes of the other submap; exact observations all stay.
  EXPECT_GT(junction.joined, 240 * kKeyframesPerSubmap);
  EXPECT_EQ(junction.kept, junction.joined);
  EXPECT_TRUE(CheckJunctions(merged, {TreeEdge()}, AcceptanceOptions()).empty());
}

TEST(MergedMap, AMergeOnPointsThatAreNotTheSameIsDoubtedAfterPlacement) {
  const TwoSubmaps scene = MakeTwoSubmaps();
  // The connection's matches pair each point with another one (repeated texture, say), and B is
  // placed 20 degrees off by them: fusing joins points the adjustment cannot reconcile, and
  // fusing by projection finds nothing where B wrongly lies.
  ConnectedFrame wrong = FewMatches(scene);
  for (size_t m = 0; m < wrong.point_pairs.size(); ++m) {
    wrong.point_pairs[m].second = scene.same_points[(m + 97) % kPoints].second;
  }
  const Sim3d far_off(1.0, Eigen::Quaterniond(Eigen::AngleAxisd(20 * M_PI / 180, Eigen::Vector3d::UnitX())),
                      Eigen::Vector3d(1, 0, 0));
  const MergedMap merged = AssembleAlong(scene, far_off, wrong);
  const Junction& junction = merged.junctions.at(SubmapPair(kA, kB));
  std::printf("joining observations: %d made, %d kept\n", junction.joined, junction.kept);
  EXPECT_GE(junction.joined, 40 * kKeyframesPerSubmap);
  EXPECT_LT(junction.kept, junction.joined / 2);
  const std::vector<DoubtedEdge> doubted = CheckJunctions(merged, {TreeEdge()}, AcceptanceOptions());
  ASSERT_EQ(doubted.size(), 1u);
  EXPECT_EQ(doubted[0].edge.b, kB);
  EXPECT_NE(doubted[0].reason.find("after placement the bundle adjustment kept"), std::string::npos)
      << doubted[0].reason;
  AcceptanceOptions lenient;
  lenient.min_junction_kept = 0;
  EXPECT_TRUE(CheckJunctions(merged, {TreeEdge()}, lenient).empty());
}

TEST(MergedMap, AMergeNoFusedPointConfirmsIsDoubtedAfterPlacement) {
  const TwoSubmaps scene = MakeTwoSubmaps();
  // B placed 2 m off and no verified matches to fuse (its connections' points culled since, say):
  // fusing by projection finds none of A's points in B's keyframes.
  ConnectedFrame unmatched = FewMatches(scene);
  unmatched.point_pairs.clear();
  const Sim3d far_off(1.0, Eigen::Quaterniond::Identity(), Eigen::Vector3d(0, 2, 0));
  const MergedMap merged = AssembleAlong(scene, far_off, unmatched);
  const auto junction = merged.junctions.find(SubmapPair(kA, kB));
  EXPECT_TRUE(junction == merged.junctions.end() || junction->second.joined < 30);
  const std::vector<DoubtedEdge> doubted = CheckJunctions(merged, {TreeEdge()}, AcceptanceOptions());
  ASSERT_EQ(doubted.size(), 1u);
  EXPECT_NE(doubted[0].reason.find("fusing found too few points"), std::string::npos) << doubted[0].reason;
  AcceptanceOptions none_needed;
  none_needed.min_junction_observations = 0;
  EXPECT_TRUE(CheckJunctions(merged, {TreeEdge()}, none_needed).empty());
}

// TUM fr1/rpy with two blackouts (issue #20): the largest merged map was a submap alone, and the
// merge of two smaller submaps, never assembled, was rolled back for the junction it had not had
// the chance to make ("0 observations join them").
TEST(MergedMap, AMergeOutsideTheAssembledMapIsNotJudgedByIt) {
  const TwoSubmaps scene = MakeTwoSubmaps();
  const MergedMap merged = AssembleMisplaced(scene, MergedMapOptions());
  SubmapEdge elsewhere = TreeEdge();
  elsewhere.a = MakeSubmapId(0, 3);
  elsewhere.b = MakeSubmapId(0, 4);
  EXPECT_TRUE(CheckJunctions(merged, {elsewhere}, AcceptanceOptions()).empty());
  AcceptanceOptions strict;  // that the edge inside would be doubted under it
  strict.min_junction_observations = 1000000;
  EXPECT_EQ(CheckJunctions(merged, {TreeEdge(), elsewhere}, strict).size(), 1u);
}

TEST(MergedMap, OnlyTheChosenMergedMapIsAssembled) {
  const TwoSubmaps scene = MakeTwoSubmaps();
  std::map<SubmapId, SubmapPlacement> placement = Placement(scene, Sim3d());
  placement[kB] = {1, kB, Sim3d(), kB};  // B is a merged map of its own
  const MergedMap merged = AssembleMergedMap(scene.submaps, placement, {}, {}, 0, ScalePyramid::From(OrbOptions()),
                                             kCamera.Intrinsics(), MergedMapOptions());
  EXPECT_EQ(merged.map.num_keyframes(), static_cast<size_t>(kKeyframesPerSubmap));
  for (const auto& [id, pose] : merged.keyframe_poses) EXPECT_EQ(SubmapOf(id), kA);
}

// Each fix of a submap becomes a prior between the two of its keyframes around its time (on the
// camera's clock), in the merged map's frame and units, whitened by its stated sigmas in ENU; a
// fix outside the keyframes' times, or across a gap wider than the interpolation allows, none.
TEST(MergedMap, FixesBecomePriorsOnTheKeyframesAroundThem) {
  Map map(SubmapId(), ScalePyramid::From(OrbOptions()));
  const Eigen::Quaterniond turn(Eigen::AngleAxisd(0.4, Eigen::Vector3d(0.3, -1, 0.2).normalized()));
  for (int k = 0; k < 4; ++k) {
    Keyframe keyframe;
    keyframe.id = MakeKeyframeId(kA, k);
    keyframe.t_ns = (k < 3 ? k : 5) * 1'000'000'000LL;  // 0, 1, 2 and 5 s
    keyframe.cam_from_world = Rigid3d(turn * Eigen::Quaterniond(Eigen::AngleAxisd(0.1 * k, Eigen::Vector3d::UnitZ())),
                                      Eigen::Vector3d(k, 0.5 * k, 3));
    map.AddKeyframe(keyframe);
  }
  GeoReferenceOptions geo;
  geo.antenna_x_m = 0.1;
  geo.antenna_y_m = -0.2;
  geo.antenna_z_m = 0.3;
  geo.time_offset_s = 0.1;
  geo.max_interpolation_gap_s = 1.5;
  const Sim3d enu_from_world(2.0, Eigen::Quaterniond(Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitZ())),
                             Eigen::Vector3d(10, -20, 5));
  const Eigen::Vector3d antenna_m(0.1, -0.2, 0.3);
  // The antenna in ENU where keyframe k puts it.
  const auto antenna_enu = [&](int k) {
    const Rigid3d world_from_cam = map.FindKeyframe(MakeKeyframeId(kA, k))->cam_from_world.Inverse();
    return enu_from_world * (world_from_cam * (antenna_m / 2.0));
  };
  SubmapFixes fixes;
  const auto fix = [](double t_s, const Eigen::Vector3d& enu) {
    EnuFix f;
    f.t_ns = static_cast<int64_t>(t_s * 1e9);
    f.enu = enu;
    f.horizontal_sigma_m = 2.0;
    f.vertical_sigma_m = 4.0;
    return f;
  };
  fixes[kA] = {fix(0.4, 0.5 * (antenna_enu(0) + antenna_enu(1))),  // 0.5 s on the camera's clock
               fix(0.9, antenna_enu(1)),                           // at keyframe 1
               fix(-0.5, antenna_enu(0)),                          // before the first keyframe
               fix(3.0, antenna_enu(2)),                           // between 2 and 5 s: a gap of 3 s
               fix(5.5, antenna_enu(3))};                          // after the last
  fixes[kB] = {fix(1.0, antenna_enu(1))};                          // no keyframe of B in the map
  const PositionPriors priors = PriorsFromFixes(map, {enu_from_world, &fixes, &geo});
  ASSERT_EQ(priors.priors.size(), 2u);
  EXPECT_EQ(priors.outlier_chi2, geo.outlier_chi2);
  const PositionPrior& between = priors.priors[0];
  EXPECT_EQ(between.before, MakeKeyframeId(kA, 0));
  EXPECT_EQ(between.after, MakeKeyframeId(kA, 1));
  EXPECT_NEAR(between.weight_after, 0.5, 1e-9);
  EXPECT_EQ(priors.priors[1].before, MakeKeyframeId(kA, 1));
  EXPECT_EQ(priors.priors[1].after, MakeKeyframeId(kA, 1));
  for (const PositionPrior& prior : priors.priors) {
    EXPECT_LT((prior.antenna_in_camera - antenna_m / 2.0).norm(), 1e-12);  // in map units
    const auto antenna = [&](KeyframeId id) {
      return map.FindKeyframe(id)->cam_from_world.Inverse() * prior.antenna_in_camera;
    };
    const Eigen::Vector3d at =
        (1 - prior.weight_after) * antenna(prior.before) + prior.weight_after * antenna(prior.after);
    EXPECT_LT((prior.sqrt_information * (at - prior.position)).norm(), 1e-9);
    // A metre east, north and up of the fix: half a sigma, half a sigma and a quarter.
    const Sim3d world_from_enu = enu_from_world.Inverse();
    for (int axis = 0; axis < 3; ++axis) {
      const Eigen::Vector3d off = world_from_enu * (enu_from_world * prior.position + Eigen::Vector3d::Unit(axis));
      const Eigen::Vector3d whitened = prior.sqrt_information * (off - prior.position);
      EXPECT_NEAR(whitened.norm(), axis < 2 ? 0.5 : 0.25, 1e-9);
      EXPECT_NEAR(std::abs(whitened[axis]), whitened.norm(), 1e-9);
    }
  }
}

}  // namespace
}  // namespace stitch
