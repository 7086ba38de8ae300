#pragma once
// The survey flight of the synthetic default: a UAV with a downward-looking camera flies an
// S-shaped lawnmower path (parallel strips with side overlap, joined by half-turns), with a little
// wind jitter, and gusts at scheduled frames that knock it off course (yaw, altitude, sideways)
// for a while. Ground truth is exact: the renderer draws exactly these poses.

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "stitch/geometry/camera.h"
#include "stitch/geometry/rigid3.h"
#include "stitch/io/failure_schedule.h"

namespace stitch {

struct FlightOptions {
  int num_frames = 1000;
  double fps = 20.0;
  double altitude_m = 70.0;  // above the terrain's mean height
  // survey: parallel strips joined by half-turns (an S-shaped lawnmower survey); road: straight
  // legs joined by quarter turns, left and right in turn (a car or a low corridor flight).
  std::string path = "survey";
  int num_strips = 4;             // survey strips, or road legs
  double strip_length_m = 240.0;  // length of each strip or leg
  double side_overlap = 0.6;      // survey: fraction of the footprint shared by neighbouring strips
  double turn_radius_m = 12.0;    // road: radius of its turns
  double camera_pitch_deg = 0.0;  // 0: straight down (nadir); 90: straight ahead at the horizon
  // Roll into each turn (a banking aircraft), ramped in and out. A survey's half-turn is then as
  // wide as that bank turns at the flight's speed (radius v^2 / (g tan(bank))): between strips
  // closer than twice that radius it swings out first (an omega turn) and takes longer.
  double turn_bank_deg = 0.0;
  double view_distance_m = 0.0;      // farthest ground drawn when the horizon is in view (0: 25 x altitude, 150-400 m)
  double attitude_jitter_deg = 1.0;  // wind: slow roll / pitch wobble
  double altitude_jitter_m = 1.0;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("num_frames", num_frames, "frames in the flight");
    v("fps", fps, "camera frame rate, Hz");
    v("altitude_m", altitude_m, "flight height above the mean terrain, metres");
    v("path", path, "survey (parallel strips joined by half-turns) or road (legs joined by quarter turns)");
    v("num_strips", num_strips, "survey strips, or road legs");
    v("strip_length_m", strip_length_m, "length of each strip or leg, metres");
    v("side_overlap", side_overlap, "survey: fraction of the footprint shared by neighbouring strips");
    v("turn_radius_m", turn_radius_m, "road: radius of its turns, metres");
    v("camera_pitch_deg", camera_pitch_deg, "camera tilt from straight down (0) towards straight ahead (90), degrees");
    v("turn_bank_deg", turn_bank_deg,
      "roll into each turn, degrees; a survey's turns are then as wide as that bank flies them (0: level "
      "half-turns between neighbouring strips)");
    v("view_distance_m", view_distance_m,
      "farthest ground drawn when the horizon is in view, metres (0: 25 x altitude, within 150-400)");
    v("attitude_jitter_deg", attitude_jitter_deg, "slow roll/pitch wobble amplitude, degrees");
    v("altitude_jitter_m", altitude_jitter_m, "slow altitude wobble amplitude, metres");
  }
  bool Check(std::string* why) const;
};

struct GustOptions {
  double yaw_deg = 60.0;          // heading change a gust causes
  double altitude_change = 0.25;  // fraction of the altitude gained or lost
  double lateral_m = 25.0;        // sideways push
  double shake_deg = 12.0;        // roll / pitch shaking during the gust
  // Motion blur length during the gust, pixels of a camera with a 450-pixel focal length (the
  // default's); another camera gets the same angle (1080p at 1350 px: 135 pixels).
  double blur_px = 45.0;
  int recovery_frames = 90;  // frames to return to the planned path afterwards

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("yaw_deg", yaw_deg, "heading change a gust causes, degrees");
    v("altitude_change", altitude_change, "fraction of the altitude gained or lost in a gust");
    v("lateral_m", lateral_m, "sideways push of a gust, metres");
    v("shake_deg", shake_deg, "roll/pitch shaking during a gust, degrees");
    v("blur_px", blur_px,
      "motion blur length during a gust, pixels at a 450-pixel focal length (the same angle for any camera)");
    v("recovery_frames", recovery_frames, "frames to return to the planned path after a gust");
  }
  bool Check(std::string* why) const;
};

class FlightPlan {
 public:
  // `camera` sets the footprint (and so the strip spacing). Throws stitch::Error on bad options.
  FlightPlan(const FlightOptions& flight, const GustOptions& gust, const Camera& camera, const FailureSchedule& gusts,
             uint64_t seed);

  int num_frames() const { return flight_.num_frames; }
  int64_t TimestampNs(int frame) const;
  Rigid3d WorldFromCam(int frame) const { return poses_.at(frame); }
  const std::vector<Rigid3d>& world_from_cam() const { return poses_; }
  bool InGust(int frame) const { return gusts_.Contains(frame); }
  const FailureSchedule& gusts() const { return gusts_; }
  // Motion blur of a gust frame: length (px of the camera's images) and direction (rad); length
  // 0 outside gusts.
  std::pair<double, double> GustBlur(int frame) const;
  double strip_spacing_m() const { return strip_spacing_; }
  // The whole path flown (its frames may end before it does: a survey's banked turns are longer
  // than the half-turns its speed was planned with).
  double path_length_m() const { return path_length_; }
  double speed_m_per_s() const { return speed_; }
  // A survey's turn radius: half the strip spacing, or what the bank needs at the speed.
  double survey_turn_radius_m() const { return survey_turn_radius_; }
  // Bounds of the ground the camera can see over the whole flight, with a margin.
  Eigen::Vector2d min_ground_xy() const { return min_xy_; }
  Eigen::Vector2d max_ground_xy() const { return max_xy_; }

 private:
  // Planned position and heading at arc length s along the path, and how far into a turn (signed:
  // positive turning left; 0 on straight parts, +-1 in the middle of a turn).
  void PathAt(double s, Eigen::Vector2d* position, double* heading, double* turning) const;
  void SurveyAt(double s, Eigen::Vector2d* position, double* heading, double* turning) const;
  void RoadAt(double s, Eigen::Vector2d* position, double* heading, double* turning) const;

  FlightOptions flight_;
  GustOptions gust_;
  FailureSchedule gusts_;
  uint64_t seed_;
  double blur_per_px_ = 1;  // the camera's pixels per pixel of a 450-pixel focal length
  // One turn from strip to strip: a half-turn of radius spacing / 2, or an omega turn (out,
  // around, back in) of the larger radius.
  double SurveyTurnLength() const;
  void SurveyTurnAt(double along, const Eigen::Vector2d& end, double strip_y, double direction,
                    Eigen::Vector2d* position, double* heading, double* turning) const;

  double strip_spacing_ = 0;
  double path_length_ = 0;
  double speed_ = 0;
  double survey_turn_radius_ = 0;
  std::vector<Rigid3d> poses_;
  Eigen::Vector2d min_xy_, max_xy_;
};

}  // namespace stitch
