#include "stitch/io/trajectory.h"

#include <fstream>

#include <gtest/gtest.h>

#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

TEST(Trajectory, TumRoundTripKeepsNanoseconds) {
  testing::TempDir dir;
  Trajectory t;
  t.Add({1403715273262142976LL,
         Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitY())), Eigen::Vector3d(1, 2, 3))});
  t.Add({1403715273212142976LL, Rigid3d()});  // out of order on purpose
  t.WriteTum(dir / "t.tum");
  const Trajectory back = Trajectory::ReadTum(dir / "t.tum");
  ASSERT_EQ(back.size(), 2u);
  EXPECT_EQ(back.poses()[0].t_ns, 1403715273212142976LL);
  EXPECT_EQ(back.poses()[1].t_ns, 1403715273262142976LL);
  EXPECT_NEAR((back.poses()[1].world_from_cam.translation - Eigen::Vector3d(1, 2, 3)).norm(), 0, 1e-8);
}

TEST(Trajectory, InterpolatesBetweenSamplesOnly) {
  Trajectory t({{0, Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0, 0, 0))},
                {10'000'000, Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitZ())),
                                     Eigen::Vector3d(1, 0, 0))}});
  const auto mid = t.PoseAt(5'000'000);
  ASSERT_TRUE(mid);
  EXPECT_NEAR(mid->translation.x(), 0.5, 1e-12);
  EXPECT_NEAR(RotationAngle(mid->rotation), 0.1, 1e-9);
  EXPECT_FALSE(t.PoseAt(-1'000'000));
  EXPECT_FALSE(t.PoseAt(20'000'000));
  EXPECT_FALSE(t.PoseAt(5'000'000, 1'000'000));  // gap wider than allowed
}

TEST(Trajectory, MalformedLineNamesFileAndLine) {
  testing::TempDir dir;
  std::ofstream(dir / "bad.tum") << "# comment\n1.0 0 0 0 0 0 0 1\n2.0 0 0 zero 0 0 0 1\n";
  try {
    Trajectory::ReadTum(dir / "bad.tum");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("bad.tum:3"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace stitch
