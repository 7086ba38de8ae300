// The synthetic GNSS receiver: fixes at its rate where the camera truly was, with the noise,
// dropouts, jumps and offset it is told to have.

#include "stitch/synthetic/gnss_receiver.h"

#include <cmath>

#include <gtest/gtest.h>

#include "stitch/util/error.h"

namespace stitch {
namespace {

// 60 s at 20 Hz along x at 2 m/s, 70 m up.
Trajectory StraightFlight() {
  Trajectory truth;
  for (int i = 0; i <= 1200; ++i) {
    truth.Add({1'000'000'000LL + i * 50'000'000LL, Rigid3d(Eigen::Quaterniond::Identity(), {0.1 * i, 5.0, 70.0})});
  }
  return truth;
}

struct Offsets {
  std::vector<double> east, north, up, t_s;
};

Offsets FixOffsets(const GnssTrack& track, const Trajectory& truth) {
  const LocalTangentPlane plane(*track.ground_truth_enu_origin);
  Offsets o;
  for (const GnssFix& f : track.fixes) {
    const Eigen::Vector3d d = plane.ToEnu(f.position) - truth.PoseAt(f.t_ns)->translation;
    o.east.push_back(d.x());
    o.north.push_back(d.y());
    o.up.push_back(d.z());
    o.t_s.push_back(f.t_ns * 1e-9);
  }
  return o;
}

double Rms(const std::vector<double>& values) {
  double sum = 0;
  for (double v : values) sum += v * v;
  return std::sqrt(sum / values.size());
}

TEST(GnssReceiver, FixesTheTruePositionsAtItsRateWithItsNoise) {
  const Trajectory truth = StraightFlight();
  GnssReceiverOptions options;
  const GnssTrack track = SimulateGnssReceiver(truth, options, 1);
  ASSERT_EQ(track.fixes.size(), 301u);  // 60 s at 5 Hz, both ends
  EXPECT_EQ(track.fixes[1].t_ns - track.fixes[0].t_ns, 200'000'000);
  ASSERT_TRUE(track.ground_truth_enu_origin);
  EXPECT_EQ(track.ground_truth_enu_origin->latitude_deg, options.origin_latitude_deg);
  EXPECT_DOUBLE_EQ(track.fixes[0].horizontal_accuracy_m, 2.0);
  const Offsets o = FixOffsets(track, truth);
  EXPECT_NEAR(Rms(o.east), 2.0, 0.3);
  EXPECT_NEAR(Rms(o.north), 2.0, 0.3);
  EXPECT_NEAR(Rms(o.up), 3.0, 0.45);
  // Deterministic from the seed, and another seed draws other noise.
  EXPECT_EQ(SimulateGnssReceiver(truth, options, 1).fixes[7].position.latitude_deg,
            track.fixes[7].position.latitude_deg);
  EXPECT_NE(SimulateGnssReceiver(truth, options, 2).fixes[7].position.latitude_deg,
            track.fixes[7].position.latitude_deg);
  // A part of the flight has the whole flight's fixes over that part.
  const GnssTrack part = SimulateGnssReceiver(truth.Between(20'000'000'000LL, 30'000'000'000LL), options, 1);
  ASSERT_EQ(part.fixes.size(), 51u);
  EXPECT_EQ(part.fixes[0].t_ns, 20'000'000'000LL);
  EXPECT_EQ(part.fixes[0].position.latitude_deg, track.fixes[95].position.latitude_deg);
  options.rate_hz = 0;
  EXPECT_TRUE(SimulateGnssReceiver(truth, options, 1).fixes.empty());
}

TEST(GnssReceiver, DropsJumpsAndShiftsWhereItIsTold) {
  const Trajectory truth = StraightFlight();
  GnssReceiverOptions options;
  options.horizontal_noise_m = 0.01;
  options.vertical_noise_m = 0.01;
  options.dropouts = "10:5";
  options.jumps = "30:2:100";
  options.offset_m = 20;
  options.offset_from_s = 40;
  const GnssTrack track = SimulateGnssReceiver(truth, options, 1);
  EXPECT_EQ(track.fixes.size(), 301u - 25u);
  const Offsets o = FixOffsets(track, truth);
  for (size_t i = 0; i < o.t_s.size(); ++i) {
    const double t = o.t_s[i];
    EXPECT_FALSE(t >= 10 && t < 15) << "a fix at " << t << " s, in the dropout";
    EXPECT_NEAR(o.north[i], t >= 30 && t < 32 ? 100.0 : 0.0, 0.1) << t;
    EXPECT_NEAR(o.east[i], t >= 40 ? 20.0 : 0.0, 0.1) << t;
  }
}

TEST(GnssReceiver, RefusesSchedulesItCannotRead) {
  std::string why;
  GnssReceiverOptions options;
  options.dropouts = "10";
  EXPECT_FALSE(options.Check(&why));
  EXPECT_NE(why.find("dropouts: \"10\""), std::string::npos) << why;
  options.dropouts = "10:0";
  EXPECT_FALSE(options.Check(&why));
  options.dropouts = "10:5";
  options.jumps = "3:1";
  EXPECT_FALSE(options.Check(&why));
  EXPECT_NE(why.find("jumps"), std::string::npos) << why;
  options.jumps = "3:1:x";
  EXPECT_FALSE(options.Check(&why));
  options.jumps = "3:1:50";
  EXPECT_TRUE(options.Check(&why)) << why;
  options.origin_latitude_deg = 100;
  EXPECT_FALSE(options.Check(&why));
  EXPECT_THROW(SimulateGnssReceiver(StraightFlight(), options, 1), Error);
}

}  // namespace
}  // namespace stitch
