#include "stitch/merging/gnss_junctions.h"

#include <cmath>

#include <gtest/gtest.h>

#include "stitch/util/rng.h"

namespace stitch {
namespace {

const SubmapId kA = MakeSubmapId(0, 1), kB = MakeSubmapId(0, 2), kC = MakeSubmapId(0, 3);
constexpr double kSpeed = 10.0;  // m/s east

// The truth: a nadir camera flying east at 60 m with a lateral wobble, in ENU.
Eigen::Vector3d TruePosition(double t) {
  return {kSpeed * t, 4.0 * std::sin(0.3 * t), 60.0};
}

// Three submaps of one straight flight, parted by two gusts (no view shared), each in a frame of
// its own (scale, rotation and origin of a monocular map), with the receiver's fixes over them.
struct Flight {
  std::map<SubmapId, SubmapReplica> submaps;
  std::map<SubmapId, Sim3d> submap_from_enu;
  SubmapFixes fixes;
};

Flight MakeFlight(double c_fixes_s = 20.0, double offset_north_from_s = 1e9) {
  Flight flight;
  Rng rng(7);
  const Eigen::Matrix3d enu_from_cam = Eigen::Vector3d(1, -1, -1).asDiagonal();  // x east, z down
  const std::map<SubmapId, double> start_s = {{kA, 0.0}, {kB, 24.0}, {kC, 48.0}};
  for (const auto& [id, start] : start_s) {
    const double index = static_cast<double>(SubmapNumber(id));
    const Sim3d submap_from_enu(
        0.02 * index, Eigen::Quaterniond(Eigen::AngleAxisd(0.7 * index, Eigen::Vector3d(0.3, -1, 0.5).normalized())),
        Eigen::Vector3d(index, -2 * index, 0.5));
    flight.submap_from_enu[id] = submap_from_enu;
    SubmapReplica replica(id, ScalePyramid::From(OrbOptions()));
    for (int k = 0; k < 80; ++k) {
      const double t = start + 0.25 * k;
      const Sim3d submap_from_cam = submap_from_enu * Sim3d(1.0, Eigen::Quaterniond(enu_from_cam), TruePosition(t));
      Keyframe keyframe;
      keyframe.id = MakeKeyframeId(id, k);
      keyframe.t_ns = static_cast<int64_t>(t * 1e9);
      keyframe.cam_from_world = Rigid3d(submap_from_cam.rotation, submap_from_cam.translation).Inverse();
      replica.map.AddKeyframe(keyframe);
    }
    flight.submaps.emplace(id, std::move(replica));
    const double fixes_s = id == kC ? c_fixes_s : 20.0;
    for (double t = start; t <= start + fixes_s - 0.25; t += 0.2) {
      EnuFix fix;
      fix.t_ns = static_cast<int64_t>(t * 1e9);
      fix.enu = TruePosition(t) + Eigen::Vector3d(rng.Normal(0, 2.0), rng.Normal(0, 2.0), rng.Normal(0, 3.0));
      if (t >= offset_north_from_s) fix.enu.y() += 25.0;  // a receiver that jumped for good
      fix.horizontal_sigma_m = 2.0;
      fix.vertical_sigma_m = 3.0;
      flight.fixes[id].push_back(fix);
    }
  }
  return flight;
}

std::map<SubmapId, int> Sizes(const Flight& flight) {
  std::map<SubmapId, int> sizes;
  for (const auto& [id, replica] : flight.submaps) sizes[id] = static_cast<int>(replica.map.num_keyframes());
  return sizes;
}

// The keyframes' horizontal RMS distance from the truth in metres, where `placement` puts them
// and the root's GNSS placement puts its frame.
double HorizontalRmsM(const Flight& flight, const std::map<SubmapId, SubmapPlacement>& placement,
                      const GnssJoining& joining) {
  const Sim3d& enu_from_world = joining.placements.at(placement.begin()->second.root).enu_from_map;
  double sum = 0;
  int n = 0;
  for (const auto& [id, replica] : flight.submaps) {
    for (const auto& [keyframe_id, keyframe] : replica.map.keyframes()) {
      const Eigen::Vector3d enu = enu_from_world * (placement.at(id).world_from_submap * keyframe.Centre());
      const Eigen::Vector3d truth = TruePosition(static_cast<double>(keyframe.t_ns) * 1e-9);
      sum += (enu - truth).head<2>().squaredNorm();
      ++n;
    }
  }
  return std::sqrt(sum / n);
}

TEST(JoinByGnss, JoinsTheMapsNoViewConnectsWhereTheirFixesPlaceThem) {
  const Flight flight = MakeFlight();
  const std::map<SubmapId, SubmapPlacement> apart = PlaceSubmaps(Sizes(flight), {});
  ASSERT_EQ(apart.at(kC).component, 2);
  const GnssJoining joining = JoinByGnss(flight.submaps, apart, flight.fixes, GeoReferenceOptions());
  ASSERT_EQ(joining.junctions.size(), 2u);
  // Each where a gust parted them: A-B and B-C, not both to the root.
  EXPECT_EQ(joining.junctions[0].a, kA);
  EXPECT_EQ(joining.junctions[0].b, kB);
  EXPECT_EQ(joining.junctions[1].a, kB);
  EXPECT_EQ(joining.junctions[1].b, kC);
  for (const SubmapEdge& junction : joining.junctions) {
    EXPECT_EQ(junction.kind, EdgeKind::kGnss);
    // 2 m fixes, about 100 of them per map: each map's centre within a few decimetres.
    EXPECT_GT(junction.gnss_sigma_m, 0.1);
    EXPECT_LT(junction.gnss_sigma_m, 0.6);
  }
  EXPECT_EQ(joining.placements.size(), 3u);

  std::map<SubmapId, SubmapPlacement> joined = PlaceSubmaps(Sizes(flight), joining.junctions);
  for (const SubmapId id : {kA, kB, kC}) EXPECT_EQ(joined.at(id).component, 0) << SubmapName(id);
  EXPECT_LT(HorizontalRmsM(flight, joined, joining), 0.6);
  // Each submap's scale in the joined frame follows the truth's (1 % of it).
  const double root_scale = flight.submap_from_enu.at(joined.at(kA).root).scale;
  for (const SubmapId id : {kA, kB, kC}) {
    const double scale = joined.at(id).world_from_submap.scale * flight.submap_from_enu.at(id).scale / root_scale;
    EXPECT_NEAR(scale, 1.0, 0.01) << SubmapName(id);
  }
}

TEST(JoinByGnss, AViewJoinedMapIsPlacedAsOneAndJoinedOnce) {
  const Flight flight = MakeFlight();
  // A and B share views (the true similarity between their frames).
  SubmapEdge seen;
  seen.a = kA;
  seen.b = kB;
  seen.b_from_a = flight.submap_from_enu.at(kB) * flight.submap_from_enu.at(kA).Inverse();
  const std::map<SubmapId, SubmapPlacement> by_views = PlaceSubmaps(Sizes(flight), {seen});
  const GnssJoining joining = JoinByGnss(flight.submaps, by_views, flight.fixes, GeoReferenceOptions());
  ASSERT_EQ(joining.junctions.size(), 1u);
  EXPECT_EQ(joining.junctions[0].a, kB);  // C's nearest in time
  EXPECT_EQ(joining.junctions[0].b, kC);
  EXPECT_EQ(joining.placements.size(), 2u);
  std::vector<SubmapEdge> tree = {seen};
  tree.push_back(joining.junctions[0]);
  EXPECT_LT(HorizontalRmsM(flight, PlaceSubmaps(Sizes(flight), tree), joining), 0.6);
}

TEST(JoinByGnss, AMergedMapLiesOnEarthWhereThePlacementOfAnyOfItsPartsPutsIt) {
  const Flight flight = MakeFlight();
  SubmapEdge seen;  // A and B share views; C is joined by GNSS
  seen.a = kA;
  seen.b = kB;
  seen.b_from_a = flight.submap_from_enu.at(kB) * flight.submap_from_enu.at(kA).Inverse();
  const std::map<SubmapId, SubmapPlacement> by_views = PlaceSubmaps(Sizes(flight), {seen});
  GnssJoining joining = JoinByGnss(flight.submaps, by_views, flight.fixes, GeoReferenceOptions());
  ASSERT_EQ(joining.junctions.size(), 1u);
  const std::map<SubmapId, SubmapPlacement> joined = PlaceSubmaps(Sizes(flight), {seen, joining.junctions[0]});
  const SubmapId root = joined.at(kC).root;
  ASSERT_NE(root, kC);
  // A's and B's map has twice C's fixes: it places the whole; without it, C's own placement does,
  // carried through C's place in the merged map.
  for (const bool with_the_larger_part : {true, false}) {
    std::map<SubmapId, GeoPlacement> placements = joining.placements;
    if (!with_the_larger_part) placements.erase(by_views.at(kA).root);
    const std::map<int, MergedMapOnEarth> on_earth = MapsOnEarth(placements, joined);
    ASSERT_EQ(on_earth.size(), 1u);
    const MergedMapOnEarth& map = on_earth.at(0);
    EXPECT_EQ(map.inlier_fixes, placements.begin()->second.inliers);
    // Metres per unit of the merged map's frame: its root's scale against the truth's.
    EXPECT_NEAR(map.enu_from_world.scale * flight.submap_from_enu.at(root).scale, 1.0, 0.01);
    double sum = 0;
    int n = 0;
    for (const auto& [id, replica] : flight.submaps) {
      for (const auto& [keyframe_id, keyframe] : replica.map.keyframes()) {
        const Eigen::Vector3d enu = map.enu_from_world * (joined.at(id).world_from_submap * keyframe.Centre());
        sum += (enu - TruePosition(static_cast<double>(keyframe.t_ns) * 1e-9)).head<2>().squaredNorm();
        ++n;
      }
    }
    EXPECT_LT(std::sqrt(sum / n), 0.8) << (with_the_larger_part ? "A and B's placement" : "C's placement");
  }
  // A part whose fixes placed nothing puts nothing on Earth.
  for (auto& [id, geo] : joining.placements) geo.placed = false;
  EXPECT_TRUE(MapsOnEarth(joining.placements, joined).empty());
}

TEST(JoinByGnss, AMapWithTooFewFixesStaysApartAndSaysWhy) {
  const Flight flight = MakeFlight(/*c_fixes_s=*/1.0);  // 5 fixes over C
  const std::map<SubmapId, SubmapPlacement> apart = PlaceSubmaps(Sizes(flight), {});
  const GnssJoining joining = JoinByGnss(flight.submaps, apart, flight.fixes, GeoReferenceOptions());
  ASSERT_EQ(joining.junctions.size(), 1u);
  EXPECT_EQ(joining.junctions[0].a, kA);
  EXPECT_EQ(joining.junctions[0].b, kB);
  const GeoPlacement& c = joining.placements.at(kC);
  EXPECT_FALSE(c.placed);
  EXPECT_NE(c.why_not.find("fixes"), std::string::npos) << c.why_not;
}

// The receiver jumps 25 m north for good in the middle of B: B's own placement finds the later
// fixes disagreeing and holds B by the earlier ones; C, flown after the jump and sharing no view,
// could only be placed by the jumped fixes, so it is not joined, and the joining says why.
TEST(JoinByGnss, AfterAReceiverJumpedForGoodItsLaterMapsAreNotJoined) {
  const Flight flight = MakeFlight(/*c_fixes_s=*/20.0, /*offset_north_from_s=*/34.0);
  const std::map<SubmapId, SubmapPlacement> apart = PlaceSubmaps(Sizes(flight), {});
  const GnssJoining joining = JoinByGnss(flight.submaps, apart, flight.fixes, GeoReferenceOptions());
  ASSERT_TRUE(joining.placements.at(kB).disagreement);
  ASSERT_EQ(joining.junctions.size(), 1u);
  EXPECT_EQ(joining.junctions[0].a, kA);
  EXPECT_EQ(joining.junctions[0].b, kB);
  ASSERT_EQ(joining.not_joined.count(kC), 1u);
  EXPECT_NE(joining.not_joined.at(kC).find("receiver jumped for good at"), std::string::npos)
      << joining.not_joined.at(kC);
  EXPECT_NE(joining.not_joined.at(kC).find("submap 0:2"), std::string::npos) << joining.not_joined.at(kC);
  // The group's first fix: the jump's, or one before it that the noise put near the jumped place.
  const double jumped_s = joining.placements.at(kB).disagreement->first_ns * 1e-9;
  EXPECT_GT(jumped_s, 24.0);
  EXPECT_LE(jumped_s, 34.0);
  const std::map<SubmapId, SubmapPlacement> joined = PlaceSubmaps(Sizes(flight), joining.junctions);
  EXPECT_EQ(joined.at(kA).component, joined.at(kB).component);
  EXPECT_NE(joined.at(kC).component, joined.at(kA).component);
}

TEST(JoinByGnss, WithoutFixesNothingIsJoined) {
  const Flight flight = MakeFlight();
  const std::map<SubmapId, SubmapPlacement> apart = PlaceSubmaps(Sizes(flight), {});
  const GnssJoining joining = JoinByGnss(flight.submaps, apart, {}, GeoReferenceOptions());
  EXPECT_TRUE(joining.junctions.empty());
  EXPECT_TRUE(joining.placements.empty());
}

}  // namespace
}  // namespace stitch
