#include "stitch/synthetic/flight.h"

#include <gtest/gtest.h>

#include "stitch/util/error.h"

namespace stitch {
namespace {

const Camera kCamera = Camera::Pinhole(640, 480, 450, 450, 319.5, 239.5);

TEST(FlightPlan, FliesParallelStripsWithTheRequestedSideOverlap) {
  FlightOptions options;
  options.attitude_jitter_deg = 0;
  options.altitude_jitter_m = 0;
  const FlightPlan plan(options, GustOptions(), kCamera, FailureSchedule(), 1);
  const double footprint = 640 * options.altitude_m / 450;
  EXPECT_NEAR(plan.strip_spacing_m(), (1 - options.side_overlap) * footprint, 1e-9);
  // First frame at the start of strip 0, last at the end of the last strip.
  EXPECT_NEAR((plan.WorldFromCam(0).translation - Eigen::Vector3d(0, 0, options.altitude_m)).norm(), 0, 1e-9);
  const Eigen::Vector3d last = plan.WorldFromCam(options.num_frames - 1).translation;
  EXPECT_NEAR(last.y(), (options.num_strips - 1) * plan.strip_spacing_m(), 1e-6);
  EXPECT_NEAR(last.x(), options.num_strips % 2 == 0 ? 0.0 : options.strip_length_m, 1e-6);
  // The camera looks straight down, image top towards the flight direction.
  const Eigen::Matrix3d r = plan.WorldFromCam(5).RotationMatrix();
  EXPECT_NEAR(r.col(2).z(), -1.0, 1e-9);  // optical axis down
  EXPECT_NEAR(r.col(1).x(), -1.0, 1e-9);  // image down = backwards on strip 0 (+x)
  // Equal steps along the path, about path length / frames.
  const double step = plan.path_length_m() / (options.num_frames - 1);
  for (int i = 1; i < options.num_frames; ++i) {
    const double d = (plan.WorldFromCam(i).translation - plan.WorldFromCam(i - 1).translation).norm();
    ASSERT_NEAR(d, step, 0.02 * step) << "frame " << i;
  }
}

TEST(FlightPlan, GustsKnockTheUavOffCourseThenItRecovers) {
  FlightOptions options;
  GustOptions gust;
  const FailureSchedule gusts = FailureSchedule::Parse("100:10");
  const FlightPlan calm(options, gust, kCamera, FailureSchedule(), 3);
  const FlightPlan windy(options, gust, kCamera, gusts, 3);
  for (int i = 0; i < 100; ++i) {
    ASSERT_NEAR((calm.WorldFromCam(i).translation - windy.WorldFromCam(i).translation).norm(), 0, 1e-9);
  }
  const Rigid3d off = calm.WorldFromCam(109).Inverse() * windy.WorldFromCam(109);
  EXPECT_GT(RotationAngle(off.rotation) * 180 / M_PI, 0.6 * gust.yaw_deg);
  EXPECT_GT((calm.WorldFromCam(109).translation - windy.WorldFromCam(109).translation).norm(), 0.6 * gust.lateral_m);
  const int back = 110 + gust.recovery_frames;
  EXPECT_NEAR((calm.WorldFromCam(back).translation - windy.WorldFromCam(back).translation).norm(), 0, 1e-6);
  EXPECT_GT(windy.GustBlur(105).first, 0);
  EXPECT_EQ(windy.GustBlur(111).first, 0);
}

TEST(FlightPlan, TiltsTheCameraForwardByItsPitch) {
  FlightOptions options;
  options.attitude_jitter_deg = 0;
  options.altitude_jitter_m = 0;
  for (const double pitch : {0.0, 45.0, 80.0}) {
    options.camera_pitch_deg = pitch;
    const FlightPlan plan(options, GustOptions(), kCamera, FailureSchedule(), 1);
    // On strip 0 (flying along +x) the optical axis leans from straight down towards +x.
    const Eigen::Vector3d axis = plan.WorldFromCam(5).RotationMatrix().col(2);
    EXPECT_NEAR(axis.z(), -std::cos(pitch * M_PI / 180), 1e-9) << pitch;
    EXPECT_NEAR(axis.x(), std::sin(pitch * M_PI / 180), 1e-9) << pitch;
    EXPECT_NEAR(axis.y(), 0, 1e-9) << pitch;
    // Looking far ahead, the ground the camera may see reaches well beyond the footprint.
    if (pitch == 80.0) EXPECT_GT(plan.max_ground_xy().x() - options.strip_length_m, 150);
  }
}

TEST(FlightPlan, BanksIntoTurnsAndFliesLevelOnStraights) {
  FlightOptions options;
  options.attitude_jitter_deg = 0;
  options.altitude_jitter_m = 0;
  options.turn_bank_deg = 25;
  const FlightPlan plan(options, GustOptions(), kCamera, FailureSchedule(), 1);
  // Roll: the angle of the image's x axis out of the horizontal plane.
  const auto roll_deg = [&](int frame) {
    return std::asin(plan.WorldFromCam(frame).RotationMatrix().col(0).z()) * 180 / M_PI;
  };
  EXPECT_NEAR(roll_deg(10), 0, 1e-6);  // on strip 0
  // The middle of the first half-turn: between the strips, at the path length's matching frame.
  const double turn_middle_s = options.strip_length_m + M_PI * plan.strip_spacing_m() / 4;
  const int frame = static_cast<int>(std::lround(turn_middle_s / plan.path_length_m() * (options.num_frames - 1)));
  EXPECT_NEAR(std::abs(roll_deg(frame)), 25, 1.0);
}

TEST(FlightPlan, ARoadDrivesLegsJoinedByQuarterTurnsAtItsHeight) {
  FlightOptions options;
  options.path = "road";
  options.num_strips = 3;
  options.strip_length_m = 100;
  options.turn_radius_m = 10;
  options.altitude_m = 1.5;
  options.camera_pitch_deg = 88;
  options.attitude_jitter_deg = 0;
  options.altitude_jitter_m = 0;
  const FlightPlan plan(options, GustOptions(), kCamera, FailureSchedule(), 1);
  EXPECT_NEAR(plan.path_length_m(), 300 + 2 * M_PI / 2 * 10, 1e-9);
  // Left, then right: the last leg runs along +x again, offset by two turn radii in y.
  const Eigen::Vector3d last = plan.WorldFromCam(options.num_frames - 1).translation;
  EXPECT_NEAR(last.x(), 100 + 10 + 10 + 100, 1e-6);
  EXPECT_NEAR(last.y(), 10 + 100 + 10, 1e-6);
  EXPECT_NEAR(last.z(), 1.5, 1e-9);
  // Looking ahead along +x, two degrees below the horizon.
  const Eigen::Vector3d axis = plan.WorldFromCam(options.num_frames - 1).RotationMatrix().col(2);
  EXPECT_NEAR(axis.x(), std::sin(88 * M_PI / 180), 1e-6);
  EXPECT_NEAR(axis.z(), -std::cos(88 * M_PI / 180), 1e-6);
}

TEST(FlightPlan, RejectsBadOptions) {
  FlightOptions options;
  options.side_overlap = 1.2;
  EXPECT_THROW(FlightPlan(options, GustOptions(), kCamera, FailureSchedule(), 1), Error);
  options = FlightOptions();
  options.path = "spiral";
  EXPECT_THROW(FlightPlan(options, GustOptions(), kCamera, FailureSchedule(), 1), Error);
  options = FlightOptions();
  options.camera_pitch_deg = 95;
  EXPECT_THROW(FlightPlan(options, GustOptions(), kCamera, FailureSchedule(), 1), Error);
}

}  // namespace
}  // namespace stitch
