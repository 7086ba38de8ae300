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

// A gust's blur is an angle: a camera with three times the focal length (1080p over the same
// view as 640x480) gets three times the pixels of blur, so its frames are as spoiled.
TEST(FlightPlan, AGustBlursEveryCameraByTheSameAngle) {
  const FailureSchedule gust = FailureSchedule::Parse("10:5");
  const FlightPlan default_camera(FlightOptions(), GustOptions(), Camera::Pinhole(640, 480, 450, 450, 320, 240), gust,
                                  1);
  const FlightPlan hd_camera(FlightOptions(), GustOptions(), Camera::Pinhole(1920, 1080, 1350, 1350, 960, 540), gust,
                             1);
  for (int frame = 10; frame < 15; ++frame) {
    const auto [length, angle] = default_camera.GustBlur(frame);
    EXPECT_GE(length, 0.7 * GustOptions().blur_px) << frame;
    EXPECT_NEAR(hd_camera.GustBlur(frame).first, 3 * length, 1e-9) << frame;
    EXPECT_EQ(hd_camera.GustBlur(frame).second, angle) << frame;
  }
  EXPECT_EQ(hd_camera.GustBlur(20).first, 0);
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
    if (pitch == 80.0) {
      EXPECT_GT(plan.max_ground_xy().x() - options.strip_length_m, 150);
    }
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
  // Fully banked in the turns (each ramps the bank in and out).
  double most = 0;
  for (int i = 0; i < options.num_frames; ++i) most = std::max(most, std::abs(roll_deg(i)));
  EXPECT_NEAR(most, 25, 1e-6);
}

// A banked turn is as wide as its bank turns at the flight's speed (v^2 / r = g tan(bank)). The
// forward case's survey joined strips 8.5 m apart with half-turns of radius 4.25 m at 20 m/s,
// 270 degrees a second, which a 25-degree bank cannot fly (13 degrees a second, radius 87 m):
// it now swings out and around (an omega turn) and comes back onto the next strip.
TEST(FlightPlan, FliesABankedTurnAsWideAsItsBankNeeds) {
  FlightOptions options;
  options.attitude_jitter_deg = 0;
  options.altitude_jitter_m = 0;
  options.turn_bank_deg = 25;
  options.altitude_m = 15;  // the forward case's strips, 8.5 m apart
  const FlightPlan plan(options, GustOptions(), kCamera, FailureSchedule(), 1);
  const double speed = plan.speed_m_per_s();
  const double tilt = std::tan(25 * M_PI / 180);
  EXPECT_NEAR(plan.survey_turn_radius_m(), speed * speed / (9.81 * tilt), 1e-9);
  EXPECT_GT(plan.survey_turn_radius_m(), 4 * plan.strip_spacing_m());
  // One speed all along: equal steps.
  const double step = speed / options.fps;
  for (int i = 1; i < options.num_frames; ++i) {
    ASSERT_NEAR((plan.WorldFromCam(i).translation - plan.WorldFromCam(i - 1).translation).norm(), step, 0.01 * step)
        << "frame " << i;
  }
  // Turning at g tan(bank) / v where fully banked, never faster.
  const auto heading = [&](int frame) {
    const Eigen::Vector3d back = plan.WorldFromCam(frame).RotationMatrix().col(1);  // image down: backwards
    return std::atan2(-back.y(), -back.x());
  };
  const auto roll_deg = [&](int frame) {
    return std::asin(plan.WorldFromCam(frame).RotationMatrix().col(0).z()) * 180 / M_PI;
  };
  double fastest = 0;
  int banked = 0;
  for (int i = 1; i + 1 < options.num_frames; ++i) {
    double turned = heading(i + 1) - heading(i - 1);
    turned = std::atan2(std::sin(turned), std::cos(turned));
    const double rate = std::abs(turned) * options.fps / 2;
    fastest = std::max(fastest, rate);
    if (std::abs(std::abs(roll_deg(i)) - 25) < 0.01) {
      ++banked;
      ASSERT_NEAR(rate, 9.81 * tilt / speed, 0.01 * rate) << "frame " << i;
    }
  }
  EXPECT_GT(banked, 100);
  EXPECT_LT(fastest, 1.01 * 9.81 * tilt / speed);
  // Back onto the next strip, heading back along it, at one strip spacing from the first.
  const double turn_length = plan.survey_turn_radius_m() * 7;  // about pi + 4 x 58 degrees
  const int on_strip_1 = static_cast<int>((options.strip_length_m + turn_length + 20) / step);
  const Eigen::Vector3d back_on = plan.WorldFromCam(on_strip_1).translation;
  EXPECT_NEAR(back_on.y(), plan.strip_spacing_m(), 1e-6);
  EXPECT_LT(back_on.x(), options.strip_length_m);
  EXPECT_NEAR(std::cos(heading(on_strip_1)), -1, 1e-9);
  // The frames end before the longer path does.
  EXPECT_LT(static_cast<double>(options.num_frames - 1) * step, plan.path_length_m());
  // Without a bank, the half-turns the speed was planned with.
  options.turn_bank_deg = 0;
  const FlightPlan level(options, GustOptions(), kCamera, FailureSchedule(), 1);
  EXPECT_NEAR(level.survey_turn_radius_m(), level.strip_spacing_m() / 2, 1e-12);
  EXPECT_NEAR(level.path_length_m(), static_cast<double>(options.num_frames - 1) * step, 1e-6);
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
