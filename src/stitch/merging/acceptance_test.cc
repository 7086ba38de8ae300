// The merger's acceptance checks (docs/merger.md, "Acceptance"): connections whose geometry
// cannot pin a similarity, edges decided by one place or by a split vote, cycles that do not
// close, and connections verified on a submap's older points.

#include <gtest/gtest.h>

#include "stitch/merging/merger.h"
#include "stitch/testing/default_vocabulary.h"
#include "stitch/testing/submap_updates.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

const Camera kCamera = Camera::Pinhole(640, 480, 450, 450, 319.5, 239.5);

SubmapId S(char name) {
  return MakeSubmapId(0, name - 'A' + 1);
}

Sim3d Turned(double degrees, const Eigen::Vector3d& axis, const Sim3d& s = Sim3d()) {
  Sim3d turned = s;
  turned.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(degrees * M_PI / 180.0, axis.normalized())) * s.rotation;
  return turned;
}

// Camera a at the origin and camera b 2 m to its right, both looking along +z; b's submap frame
// is `b_from_a` of a's. Each point is seen exactly by both.
struct Correspondences {
  std::vector<Sim3Correspondence> pairs;
  std::vector<char> inlier;
  Sim3d b_from_a{0.5, Eigen::Quaterniond(Eigen::AngleAxisd(0.4, Eigen::Vector3d(0.3, 1, 0.2).normalized())),
                 Eigen::Vector3d(1, -2, 0.5)};
  Rigid3d cam_b_from_b;
};

Correspondences SeenByBoth(const std::vector<Eigen::Vector3d>& points_in_a) {
  Correspondences c;
  // Camera b in b's units: scaled by b's scale after the rigid motion from a's frame, so the
  // composition is rigid.
  const Sim3d cam_b_from_b = Sim3d(c.b_from_a.scale, Eigen::Quaterniond::Identity(), Eigen::Vector3d::Zero()) *
                             Sim3d(1, Eigen::Quaterniond::Identity(), Eigen::Vector3d(-2, 0, 0)) * c.b_from_a.Inverse();
  c.cam_b_from_b = Rigid3d(cam_b_from_b.rotation, cam_b_from_b.translation);
  const PinholeIntrinsics k = kCamera.Intrinsics();
  for (const Eigen::Vector3d& p : points_in_a) {
    Sim3Correspondence m;
    m.point_a = p;
    m.point_b = c.b_from_a * p;
    m.pixel_a = k.Project(p);
    m.pixel_b = k.Project(c.cam_b_from_b * m.point_b);
    c.pairs.push_back(m);
    c.inlier.push_back(1);
  }
  return c;
}

ConnectionGeometry Measure(const Correspondences& c, const Sim3d& b_from_a) {
  return MeasureConnectionGeometry(c.pairs, c.inlier, b_from_a, c.cam_b_from_b, kCamera.Intrinsics());
}

TEST(Acceptance, PointsSpreadOverTheViewPassAndAgreeInDepthUnderTheTrueSimilarity) {
  Rng rng(3);
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < 60; ++i) points.emplace_back(rng.Uniform(-3, 5), rng.Uniform(-3, 3), rng.Uniform(9, 12));
  const Correspondences c = SeenByBoth(points);
  const ConnectionGeometry g = Measure(c, c.b_from_a);
  EXPECT_GT(g.line_ratio, 0.3);
  EXPECT_GT(g.bearing_spread_a, 0.1);
  EXPECT_GT(g.bearing_spread_b, 0.1);
  EXPECT_LT(g.depth_disagreement, 1e-9);
  EXPECT_EQ(RefuseConnection(g, AcceptanceOptions()), "");
  // A similarity 20 degrees off puts a's points metres from b's.
  EXPECT_GT(Measure(c, Turned(20, Eigen::Vector3d::UnitX(), c.b_from_a)).depth_disagreement, 0.1);
}

TEST(Acceptance, PointsOnALineAreRefused) {
  Rng rng(4);
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < 60; ++i) {
    const double t = rng.Uniform(-3, 5);
    points.emplace_back(t, 0.3 * t + rng.Uniform(-0.01, 0.01), 10 + 0.2 * t + rng.Uniform(-0.01, 0.01));
  }
  const Correspondences c = SeenByBoth(points);
  const ConnectionGeometry g = Measure(c, c.b_from_a);
  EXPECT_LT(g.line_ratio, 0.01);
  EXPECT_NE(RefuseConnection(g, AcceptanceOptions()).find("points near a line"), std::string::npos);
}

TEST(Acceptance, PointsSeenAlongParallelRaysAreRefused) {
  // A cluster 5 cm across at 10 m: its rays from either camera are within a third of a degree.
  Rng rng(5);
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < 60; ++i) {
    points.emplace_back(1 + rng.Uniform(-0.025, 0.025), rng.Uniform(-0.025, 0.025), 10 + rng.Uniform(-0.025, 0.025));
  }
  const Correspondences c = SeenByBoth(points);
  const ConnectionGeometry g = Measure(c, c.b_from_a);
  EXPECT_GT(g.line_ratio, AcceptanceOptions().min_line_ratio);  // not a line: a ball
  EXPECT_LT(std::min(g.bearing_spread_a, g.bearing_spread_b), 0.005);
  EXPECT_NE(RefuseConnection(g, AcceptanceOptions()).find("rays near parallel"), std::string::npos);
}

ConnectedFrame Connection(SubmapId a, int ka, SubmapId b, int kb, const Sim3d& b_from_a, int points) {
  ConnectedFrame c;
  c.keyframe_a = MakeKeyframeId(a, ka);
  c.keyframe_b = MakeKeyframeId(b, kb);
  c.b_from_a = b_from_a;
  c.map_points = points;
  c.median_angle_deg = 30;
  return c;
}

TEST(Acceptance, AnEdgeOfOneConnectedFrameWaits) {
  const Sim3d b_from_a = Turned(30, Eigen::Vector3d::UnitZ());
  std::vector<SubmapEdge> edges = SummarizeConnections({Connection(S('A'), 3, S('B'), 1, b_from_a, 80)});
  ASSERT_EQ(edges.size(), 1u);
  EXPECT_GT(edges[0].strength, 10);  // strong enough by C alone
  CheckEdges(&edges, 10, AcceptanceOptions());
  EXPECT_NE(edges[0].refused.find("1 agreeing connected frame"), std::string::npos) << edges[0].refused;
  EXPECT_TRUE(MinimumSpanningForest({S('A'), S('B')}, edges, 10).empty());
  EXPECT_EQ(EdgeStatus(edges[0], {}, 10).rfind("refused: ", 0), 0u);

  // A second connected frame that agrees lets it merge.
  edges = SummarizeConnections(
      {Connection(S('A'), 3, S('B'), 1, b_from_a, 80), Connection(S('A'), 5, S('B'), 2, b_from_a, 30)});
  CheckEdges(&edges, 10, AcceptanceOptions());
  EXPECT_EQ(edges[0].refused, "");
  const auto tree = MinimumSpanningForest({S('A'), S('B')}, edges, 10);
  EXPECT_EQ(tree.size(), 1u);
  EXPECT_EQ(EdgeStatus(edges[0], tree, 10), "merged");
}

// Campaign flight-010 of issue #20: behind a 100 kB/s link with 18% loss, most keyframes of the
// long submap never reached the ground, and the short one was placed on the few early ones.
TEST(Acceptance, AnEdgeToASubmapMissingMostOfItsKeyframesWaits) {
  const Sim3d b_from_a = Turned(30, Eigen::Vector3d::UnitZ());
  const auto edges_with = [&](int missing_of_b) {
    std::vector<SubmapEdge> edges = SummarizeConnections(
        {Connection(S('A'), 3, S('B'), 1, b_from_a, 80), Connection(S('A'), 5, S('B'), 2, b_from_a, 30)});
    CheckEdges(&edges, 10, AcceptanceOptions());
    std::map<SubmapId, SubmapCompleteness> completeness;
    completeness[S('A')] = {20, 0};
    completeness[S('B')] = {176, missing_of_b};
    CheckCompleteness(&edges, 10, completeness, AcceptanceOptions().max_missing_keyframes);
    return edges;
  };
  const auto waiting = edges_with(145);
  ASSERT_EQ(waiting.size(), 1u);
  EXPECT_NE(waiting[0].refused.find("lacks 145 of its 176 keyframes"), std::string::npos) << waiting[0].refused;
  EXPECT_TRUE(MinimumSpanningForest({S('A'), S('B')}, waiting, 10).empty());
  // A few keyframes on their way (44 of 176 at most, the default 25%) do not hold it back.
  EXPECT_EQ(edges_with(44)[0].refused, "");
  EXPECT_NE(edges_with(45)[0].refused, "");
  // A submap whose manifest has not arrived yet lists nothing: nothing to say.
  std::vector<SubmapEdge> edges = edges_with(0);
  CheckCompleteness(&edges, 10, {{S('B'), {0, 0}}}, 0.25);
  EXPECT_EQ(edges[0].refused, "");
}

// The link-300 case of issue #20: a pair's connected frames point two ways, 35 degrees apart,
// with nearly as many points each way. Neither may place the submap.
TEST(Acceptance, AnEdgeWhoseConnectedFramesPointTwoWaysWaits) {
  const Sim3d right = Turned(100, Eigen::Vector3d::UnitZ()), wrong = Turned(35, Eigen::Vector3d::UnitX(), right);
  std::vector<ConnectedFrame> connections = {
      Connection(S('C'), 3, S('B'), 25, right, 33), Connection(S('C'), 4, S('B'), 25, right, 43),
      Connection(S('C'), 5, S('B'), 26, wrong, 44), Connection(S('C'), 7, S('B'), 26, wrong, 34),
      Connection(S('C'), 9, S('B'), 24, right, 20)};
  std::vector<SubmapEdge> edges = SummarizeConnections(connections);
  ASSERT_EQ(edges.size(), 1u);
  EXPECT_NEAR(edges[0].agreement, 96.0 / 174.0, 1e-9);
  CheckEdges(&edges, 10, AcceptanceOptions());
  EXPECT_NE(edges[0].refused.find("disagree"), std::string::npos) << edges[0].refused;
  // Each connected frame says what became of it.
  EXPECT_EQ(ConnectionVerdict(connections[2], edges, {}, 10), "outvoted");
  EXPECT_EQ(ConnectionVerdict(connections[0], edges, {}, 10).rfind("refused: ", 0), 0u);

  // With the wrong way reduced to one connected frame the vote is clear.
  connections.pop_back();
  connections[3].b_from_a = right;
  edges = SummarizeConnections(connections);
  CheckEdges(&edges, 10, AcceptanceOptions());
  EXPECT_EQ(edges[0].refused, "");
  EXPECT_EQ(edges[0].disagreeing_frames, 1);
}

// Connected frames that could not be verified again on their submaps' newer points (stale) vote
// only when the pair has no current one; otherwise they count where they agree with it.
TEST(Acceptance, StaleConnectedFramesGiveWayToCurrentOnes) {
  const Sim3d right = Turned(100, Eigen::Vector3d::UnitZ()), wrong = Turned(35, Eigen::Vector3d::UnitX(), right);
  std::vector<ConnectedFrame> connections = {
      Connection(S('C'), 5, S('B'), 26, wrong, 44), Connection(S('C'), 6, S('B'), 25, wrong, 41),
      Connection(S('C'), 7, S('B'), 26, wrong, 34), Connection(S('C'), 3, S('B'), 25, right, 23),
      Connection(S('C'), 4, S('B'), 25, right, 30)};
  // All current: the wrong way has the most points.
  std::vector<SubmapEdge> edges = SummarizeConnections(connections);
  EXPECT_TRUE(SimilaritiesAgree(edges[0].b_from_a, wrong.Inverse()));  // stored as B from C
  // The wrong three were verified on points since refined, and fail now: the right two decide,
  // and the stale ones neither outvote them nor split the vote.
  for (int i = 0; i < 3; ++i) connections[i].stale = true;
  edges = SummarizeConnections(connections);
  EXPECT_TRUE(SimilaritiesAgree(edges[0].b_from_a, right.Inverse()));
  EXPECT_EQ(edges[0].connected_frames, 2);
  EXPECT_EQ(edges[0].disagreeing_frames, 3);
  EXPECT_DOUBLE_EQ(edges[0].agreement, 1.0);
  CheckEdges(&edges, 10, AcceptanceOptions());
  EXPECT_EQ(edges[0].refused, "");
  // A stale one that agrees counts.
  connections[0].b_from_a = right;
  edges = SummarizeConnections(connections);
  EXPECT_EQ(edges[0].connected_frames, 3);
  // With no current one left, the stale ones vote among themselves.
  for (auto& c : connections) c.stale = true;
  edges = SummarizeConnections(connections);
  EXPECT_EQ(edges[0].connected_frames, 3);
}

// A-B and B-C merge; A-C is strong enough but its similarity is 10 degrees from what A-B and
// B-C compose to: the cycle does not close, and the weakest edge of it is refused.
TEST(Acceptance, AnEdgeOnACycleThatDoesNotCloseIsRefused) {
  const Sim3d b_from_a(1.2, Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ())),
                       Eigen::Vector3d(4, 0, 0));
  const Sim3d c_from_b(0.9, Eigen::Quaterniond(Eigen::AngleAxisd(-0.2, Eigen::Vector3d::UnitY())),
                       Eigen::Vector3d(3, 1, 0));
  const Sim3d c_from_a = c_from_b * b_from_a;
  const auto edges_with = [&](const Sim3d& measured_c_from_a) {
    return SummarizeConnections(
        {Connection(S('A'), 1, S('B'), 1, b_from_a, 90), Connection(S('A'), 2, S('B'), 2, b_from_a, 90),
         Connection(S('B'), 5, S('C'), 1, c_from_b, 80), Connection(S('B'), 6, S('C'), 2, c_from_b, 80),
         Connection(S('A'), 7, S('C'), 3, measured_c_from_a, 25),
         Connection(S('A'), 8, S('C'), 4, measured_c_from_a, 25)});
  };
  const std::map<SubmapId, int> sizes = {{S('A'), 10}, {S('B'), 10}, {S('C'), 10}};
  for (const bool closes : {true, false}) {
    std::vector<SubmapEdge> edges = edges_with(closes ? c_from_a : Turned(10, Eigen::Vector3d::UnitX(), c_from_a));
    CheckEdges(&edges, 10, AcceptanceOptions());
    const auto tree = MinimumSpanningForest({S('A'), S('B'), S('C')}, edges, 10);
    ASSERT_EQ(tree.size(), 2u);
    CheckCycles(&edges, tree, PlaceSubmaps(sizes, tree));
    const SubmapEdge& closing = edges[1];  // A-C, in pair order
    ASSERT_EQ(closing.b, S('C'));
    ASSERT_EQ(closing.a, S('A'));
    if (closes) {
      EXPECT_EQ(EdgeStatus(closing, tree, 10), "agrees");
    } else {
      EXPECT_NE(closing.refused.find("cycle does not close (10.0 deg"), std::string::npos) << closing.refused;
    }
  }
}

// Two submaps over the same ground (cameras 10 m up looking down), B in a frame of its own. The
// merger is fed each keyframe as the mapper sends it, then B's final state, in which B's
// mapper moved the whole submap to another frame (as a bundle adjustment of a young submap
// can turn it): the connections verified on B's first points measure the old frame until they
// are verified again.
struct GroundSubmaps {
  std::vector<Eigen::Vector3d> ground;
  std::vector<cv::Mat> descriptors;

  GroundSubmaps() {
    Rng rng(8);
    for (int p = 0; p < 2500; ++p) {
      ground.emplace_back(rng.Uniform(-6, 18), rng.Uniform(-8, 8), rng.Uniform(-0.5, 0.5));
      cv::Mat d(1, 32, CV_8U);
      for (int b = 0; b < 32; ++b) d.at<uint8_t>(0, b) = static_cast<uint8_t>(rng.UniformInt(0, 255));
      descriptors.push_back(d);
    }
  }

  static Rigid3d WorldFromCam(double x) {
    return Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX())), Eigen::Vector3d(x, 0, 10));
  }

  // The submap's map with keyframes at `xs`, in the frame `frame_from_world`; `updates` gets one
  // per keyframe, as the mapper sends them.
  Map Fly(SubmapId submap, const std::vector<double>& xs, const Sim3d& frame_from_world,
          std::vector<SubmapUpdate>* updates) const {
    Map map(submap, ScalePyramid::From(OrbOptions()));
    std::map<size_t, MapPointId> ids;
    for (size_t k = 0; k < xs.size(); ++k) {
      const Rigid3d world_from_cam = WorldFromCam(xs[k]);
      const Sim3d frame_from_cam = frame_from_world * Sim3d(1, world_from_cam.rotation, world_from_cam.translation);
      Keyframe keyframe;
      keyframe.id = MakeKeyframeId(submap, static_cast<uint32_t>(k));
      keyframe.frame_index = static_cast<int>(10 * k);
      // In the frame's units the camera moves rigidly (its scale is the submap's unit).
      keyframe.cam_from_world = Rigid3d(frame_from_cam.rotation, frame_from_cam.translation).Inverse();
      std::vector<cv::Mat> rows;
      for (size_t p = 0; p < ground.size(); ++p) {
        const Eigen::Vector3d in_cam = world_from_cam.Inverse() * ground[p];
        const Eigen::Vector2d pixel = kCamera.Intrinsics().Project(in_cam);
        if (in_cam.z() <= 0 || pixel.x() < 5 || pixel.x() > 634 || pixel.y() < 5 || pixel.y() > 474) continue;
        cv::KeyPoint keypoint(static_cast<float>(pixel.x()), static_cast<float>(pixel.y()), 31, 0);
        keypoint.octave = 0;
        keyframe.keypoints.push_back(keypoint);
        rows.push_back(descriptors[p]);
        auto [it, fresh] = ids.try_emplace(p, MakeMapPointId(submap, static_cast<uint32_t>(ids.size())));
        if (fresh) {
          MapPoint point;
          point.id = it->second;
          point.position = frame_from_world * ground[p];
          descriptors[p].row(0).copyTo(cv::Mat(1, 32, CV_8U, point.descriptor.data()));
          map.AddPoint(point);
        }
        keyframe.points.push_back(it->second);
      }
      cv::vconcat(rows, keyframe.descriptors);
      map.AddKeyframe(keyframe);
    }
    for (const auto& [id, point] : map.points()) map.UpdatePointGeometry(id);
    for (SubmapUpdate& update : testing::KeyframeByKeyframeUpdates(&map, kCamera)) updates->push_back(update);
    return map;
  }
};

TEST(Acceptance, ConnectionsVerifiedOnOlderPointsAreVerifiedAgainOnTheNewer) {
  const GroundSubmaps scene;
  const Sim3d first_frame(1.0, Eigen::Quaterniond(Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitZ())),
                          Eigen::Vector3d(2, -1, 0));
  const Sim3d final_frame = Turned(30, Eigen::Vector3d(1, 0.2, 0), first_frame);
  std::vector<SubmapUpdate> updates;
  scene.Fly(S('A'), {0, 1, 2, 3, 4, 5}, Sim3d(), &updates);
  scene.Fly(S('B'), {4, 5, 6, 7, 8, 9}, first_frame, &updates);
  std::vector<SubmapUpdate> unused;
  Map b_final = scene.Fly(S('B'), {4, 5, 6, 7, 8, 9}, final_frame, &unused);

  Merger merger(MergerOptions(), &testing::DefaultVocabulary(), ScalePyramid::From(OrbOptions()));
  for (const SubmapUpdate& update : updates) merger.Apply(update);
  ASSERT_GE(merger.connections().size(), 2u);
  const auto all_measure = [&](const Sim3d& b_frame) {
    for (const ConnectedFrame& c : merger.connections()) {
      const Sim3d expected = SubmapOf(c.keyframe_b) == S('B') ? b_frame : b_frame.Inverse();
      if (!SimilaritiesAgree(c.b_from_a, expected)) return false;
    }
    return true;
  };
  EXPECT_TRUE(all_measure(first_frame));

  // Those verified before B's last keyframe arrived are verified again, and hold as they were;
  // then nothing is stale.
  const Merger::Reverification unchanged = merger.ReverifyStaleConnections();
  EXPECT_GT(unchanged.reverified, 0);
  EXPECT_EQ(unchanged.changed, 0);
  EXPECT_EQ(unchanged.stale, 0);
  EXPECT_EQ(merger.ReverifyStaleConnections().reverified, 0);

  // B's final state, in the frame its mapper moved it to.
  merger.Apply(MakeFullSubmapUpdate(&b_final, 100, /*closed=*/true));
  EXPECT_TRUE(all_measure(first_frame)) << "stale until verified again";
  const size_t count = merger.connections().size();
  const Merger::Reverification again = merger.ReverifyStaleConnections();
  EXPECT_EQ(again.reverified, static_cast<int>(count));
  EXPECT_EQ(again.changed, static_cast<int>(count));
  EXPECT_EQ(again.stale, 0);
  EXPECT_TRUE(all_measure(final_frame));
  EXPECT_EQ(merger.ReverifyStaleConnections().reverified, 0);

  MergerOptions off;
  off.acceptance.reverify_stale_connections = false;
  Merger stale(off, &testing::DefaultVocabulary(), ScalePyramid::From(OrbOptions()));
  for (const SubmapUpdate& update : updates) stale.Apply(update);
  stale.Apply(MakeFullSubmapUpdate(&b_final, 100, /*closed=*/true));
  EXPECT_EQ(stale.ReverifyStaleConnections().reverified, 0);
}

// TUM fr1/rpy of issue #20: the mapper culls most keyframes of a rotating camera, and with them
// the keyframes of most connected frames. Their matched points remain, so fusing after placement
// still searches the two submaps for each other's points around them (in the keyframes that see
// those points), and the check after placement confirms the merge.
TEST(Acceptance, AConnectionWhoseKeyframeWasCulledStillJoinsItsSubmapsAfterPlacement) {
  const GroundSubmaps scene;
  const Sim3d b_frame(1.0, Eigen::Quaterniond(Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitZ())),
                      Eigen::Vector3d(2, -1, 0));
  const std::vector<double> a_path = {0, 1, 2, 3, 4, 5};
  std::vector<SubmapUpdate> updates;
  scene.Fly(S('A'), a_path, Sim3d(), &updates);
  scene.Fly(S('B'), {4, 5, 6, 7, 8, 9}, b_frame, &updates);
  Merger merger(MergerOptions(), &testing::DefaultVocabulary(), ScalePyramid::From(OrbOptions()));
  for (const SubmapUpdate& update : updates) merger.Apply(update);
  // A's final state lacks every keyframe of A that a connected frame names (culled by its mapper).
  std::vector<SubmapUpdate> unused;
  Map a_final = scene.Fly(S('A'), a_path, Sim3d(), &unused);
  std::set<KeyframeId> culled;
  for (const ConnectedFrame& c : merger.connections()) {
    culled.insert(SubmapOf(c.keyframe_a) == S('A') ? c.keyframe_a : c.keyframe_b);
  }
  ASSERT_GE(merger.connections().size(), 2u);
  ASSERT_LE(culled.size(), a_path.size() - 2) << "A keeps keyframes enough to keep points";
  for (KeyframeId id : culled) a_final.RemoveKeyframe(id);
  merger.Apply(MakeFullSubmapUpdate(&a_final, 100, /*closed=*/true));
  merger.ReverifyStaleConnections();

  Merger::Graph graph = merger.Solve(/*refine=*/true);
  ASSERT_EQ(graph.tree.size(), 1u);
  const MergerOptions& options = merger.options();
  const MergedMap merged =
      AssembleMergedMap(merger.submaps(), graph.placement, graph.keyframe_poses, graph.agreeing, 0,
                        ScalePyramid::From(OrbOptions()), kCamera.Intrinsics(), options.merged_map);
  EXPECT_EQ(merged.points_fused_by_connection, 0) << "pairs verified before the cull are not fused as they are";
  EXPECT_GT(merged.points_fused_by_projection, 0);
  const auto junction = merged.junctions.find(SubmapPair(S('A'), S('B')));
  ASSERT_NE(junction, merged.junctions.end());
  EXPECT_GE(junction->second.joined, options.acceptance.min_junction_observations);
  EXPECT_TRUE(CheckJunctions(merged, graph.tree, options.acceptance).empty());
}

}  // namespace
}  // namespace stitch
