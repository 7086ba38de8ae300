#include "stitch/synthetic/flight.h"

#include <algorithm>
#include <cmath>

#include "stitch/util/error.h"
#include "stitch/util/options.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

double Deg(double d) {
  return d * M_PI / 180.0;
}

// Smooth 0 -> 1 over [0, 1].
double SmoothStep(double t) {
  t = std::clamp(t, 0.0, 1.0);
  return t * t * (3 - 2 * t);
}

}  // namespace

bool FlightOptions::Check(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (num_frames < 2 || num_frames > 1000000) return fail("flight.num_frames must be in [2, 1000000]");
  if (!(fps > 0 && fps <= 1000)) return fail("flight.fps must be in (0, 1000]");
  if (!(altitude_m >= 1 && altitude_m <= 5000)) return fail("flight.altitude_m must be in [1, 5000]");
  if (path != "survey" && path != "road") return fail("flight.path must be survey or road");
  if (!(turn_radius_m >= 1 && turn_radius_m <= 10000)) return fail("flight.turn_radius_m must be in [1, 10000]");
  if (!(camera_pitch_deg >= 0 && camera_pitch_deg <= 90)) return fail("flight.camera_pitch_deg must be in [0, 90]");
  if (!(std::abs(turn_bank_deg) <= 60)) return fail("flight.turn_bank_deg must be in [-60, 60]");
  if (!(view_distance_m >= 0 && view_distance_m <= 5000)) return fail("flight.view_distance_m must be in [0, 5000]");
  if (num_strips < 1 || num_strips > 100) return fail("flight.num_strips must be in [1, 100]");
  if (!(strip_length_m > 0 && strip_length_m <= 20000)) return fail("flight.strip_length_m must be in (0, 20000]");
  if (!(side_overlap >= 0 && side_overlap < 0.95)) return fail("flight.side_overlap must be in [0, 0.95)");
  if (!(attitude_jitter_deg >= 0 && attitude_jitter_deg <= 20))
    return fail("flight.attitude_jitter_deg must be in [0, 20]");
  if (!(altitude_jitter_m >= 0)) return fail("flight.altitude_jitter_m must be >= 0");
  return true;
}

bool GustOptions::Check(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (!(std::abs(yaw_deg) <= 180)) return fail("gust.yaw_deg must be in [-180, 180]");
  if (!(altitude_change >= 0 && altitude_change < 0.6)) return fail("gust.altitude_change must be in [0, 0.6)");
  if (!(lateral_m >= 0)) return fail("gust.lateral_m must be >= 0");
  if (!(shake_deg >= 0 && shake_deg <= 45)) return fail("gust.shake_deg must be in [0, 45]");
  if (!(blur_px >= 0 && blur_px <= 400)) return fail("gust.blur_px must be in [0, 400]");
  if (recovery_frames < 1) return fail("gust.recovery_frames must be >= 1");
  return true;
}

FlightPlan::FlightPlan(const FlightOptions& flight, const GustOptions& gust, const Camera& camera,
                       const FailureSchedule& gusts, uint64_t seed)
    : flight_(flight), gust_(gust), gusts_(gusts), seed_(seed), blur_per_px_(camera.fx() / 450.0) {
  CheckOptions(flight_, "synthetic.flight");
  CheckOptions(gust_, "synthetic.gust");
  // Image x runs across the track, so the footprint width across the track is width * h / fx.
  const double footprint_across = camera.width() * flight_.altitude_m / camera.fx();
  const double footprint_along = camera.height() * flight_.altitude_m / camera.fy();
  strip_spacing_ = (1.0 - flight_.side_overlap) * footprint_across;
  // The speed is planned with half-turns between neighbouring strips (quarter turns on a road).
  const bool road = flight_.path == "road";
  const double planned_length =
      road ? flight_.num_strips * flight_.strip_length_m + (flight_.num_strips - 1) * M_PI / 2 * flight_.turn_radius_m
           : flight_.num_strips * flight_.strip_length_m + (flight_.num_strips - 1) * M_PI * strip_spacing_ / 2;
  speed_ = planned_length / (flight_.num_frames - 1) * flight_.fps;
  // A bank of b turns at g tan(b) / v: a radius of v^2 / (g tan(b)).
  constexpr double kGravity = 9.81;
  survey_turn_radius_ = strip_spacing_ / 2;
  if (!road && flight_.turn_bank_deg != 0) {
    survey_turn_radius_ =
        std::max(survey_turn_radius_, speed_ * speed_ / (kGravity * std::tan(Deg(std::abs(flight_.turn_bank_deg)))));
  }
  path_length_ = road || survey_turn_radius_ <= strip_spacing_ / 2
                     ? planned_length
                     : flight_.num_strips * flight_.strip_length_m + (flight_.num_strips - 1) * SurveyTurnLength();

  Rng rng(seed);
  // Wind: two slow sinusoids per axis with random phases.
  double phase[6], frequency[6];
  for (int k = 0; k < 6; ++k) {
    phase[k] = rng.Uniform(0, 2 * M_PI);
    frequency[k] = rng.Uniform(0.05, 0.4);  // Hz
  }
  // Each gust pushes in its own random directions.
  struct GustEffect {
    double yaw, lateral, altitude, blur_angle;
  };
  std::vector<GustEffect> effects;
  for (size_t g = 0; g < gusts_.windows().size(); ++g) {
    const double sign_yaw = rng.Uniform() < 0.5 ? -1 : 1;
    const double sign_lateral = rng.Uniform() < 0.5 ? -1 : 1;
    const double sign_altitude = rng.Uniform() < 0.5 ? -1 : 1;
    effects.push_back(
        {sign_yaw * Deg(gust_.yaw_deg) * rng.Uniform(0.8, 1.0), sign_lateral * gust_.lateral_m * rng.Uniform(0.8, 1.0),
         sign_altitude * gust_.altitude_change * flight_.altitude_m * rng.Uniform(0.8, 1.0), rng.Uniform(0, M_PI)});
  }

  min_xy_ = Eigen::Vector2d::Constant(1e18);
  max_xy_ = Eigen::Vector2d::Constant(-1e18);
  double max_altitude = 0;
  poses_.reserve(flight_.num_frames);
  for (int i = 0; i < flight_.num_frames; ++i) {
    const double t = static_cast<double>(i) / flight_.fps;
    Eigen::Vector2d position;
    double heading, turning;
    PathAt(std::min(path_length_, planned_length * i / (flight_.num_frames - 1)), &position, &heading, &turning);
    double altitude = flight_.altitude_m + flight_.altitude_jitter_m * std::sin(2 * M_PI * frequency[0] * t + phase[0]);
    double roll = Deg(flight_.attitude_jitter_deg) * std::sin(2 * M_PI * frequency[1] * t + phase[1]) +
                  0.5 * Deg(flight_.attitude_jitter_deg) * std::sin(2 * M_PI * frequency[2] * t + phase[2]);
    double pitch = Deg(flight_.attitude_jitter_deg) * std::sin(2 * M_PI * frequency[3] * t + phase[3]) +
                   0.5 * Deg(flight_.attitude_jitter_deg) * std::sin(2 * M_PI * frequency[4] * t + phase[4]);
    double yaw = heading;
    // Banking into a turn: a left turn rolls the aircraft to the left (negative about x forward).
    if (turning != 0) roll -= turning * Deg(flight_.turn_bank_deg);
    // Gusts: ramp the offsets in during the gust, let them decay during recovery.
    for (size_t g = 0; g < gusts_.windows().size(); ++g) {
      const FailureWindow& w = gusts_.windows()[g];
      double strength = 0;
      if (i >= w.start && i < w.end()) {
        strength = SmoothStep((i - w.start + 1.0) / w.length);
        const double shake = Deg(gust_.shake_deg);
        roll += shake * std::sin(1.7 * (i - w.start) + g);
        pitch += shake * std::cos(2.3 * (i - w.start) + g);
      } else if (i >= w.end()) {
        strength = 1.0 - SmoothStep((i - w.end() + 1.0) / gust_.recovery_frames);
      }
      if (strength <= 0) continue;
      yaw += strength * effects[g].yaw;
      position += strength * effects[g].lateral * Eigen::Vector2d(-std::sin(heading), std::cos(heading));
      altitude += strength * effects[g].altitude;
    }
    // Body: x forward, y left, z up. Camera: looks down (z_cam = -z_body), image top forward
    // (y_cam = -x_body), image right to the right (x_cam = -y_body); tilted forward by the
    // camera's pitch about the body's y axis (at 90 degrees it looks ahead, image top up).
    const Eigen::Quaterniond world_from_body = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
                                               Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
                                               Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX());
    Eigen::Matrix3d body_from_cam;
    body_from_cam.col(0) = -Eigen::Vector3d::UnitY();
    body_from_cam.col(1) = -Eigen::Vector3d::UnitX();
    body_from_cam.col(2) = -Eigen::Vector3d::UnitZ();
    if (flight_.camera_pitch_deg > 0) {
      body_from_cam = Eigen::AngleAxisd(-Deg(flight_.camera_pitch_deg), Eigen::Vector3d::UnitY()) * body_from_cam;
    }
    const Eigen::Quaterniond world_from_cam = (world_from_body * Eigen::Quaterniond(body_from_cam)).normalized();
    poses_.emplace_back(world_from_cam, Eigen::Vector3d(position.x(), position.y(), altitude));
    min_xy_ = min_xy_.cwiseMin(position);
    max_xy_ = max_xy_.cwiseMax(position);
    max_altitude = std::max(max_altitude, altitude);
  }
  // Ground the camera may see: half the footprint diagonal at the highest altitude, with room
  // for the attitude (shaking tilts the view).
  double reach = 0.5 * std::hypot(footprint_across, footprint_along) * max_altitude / flight_.altitude_m +
                 max_altitude * std::tan(Deg(gust_.shake_deg + 2 * flight_.attitude_jitter_deg)) + 10.0;
  if (flight_.camera_pitch_deg > 0 || flight_.turn_bank_deg != 0) {
    // A tilted camera sees as far as its farthest image corner's ray (the half diagonal field of
    // view beyond the tilt, with the bank and the shaking); at the horizon, the view distance.
    const double half_diagonal = std::atan(0.5 * std::hypot(camera.width(), camera.height()) / camera.fx());
    const double far = Deg(flight_.camera_pitch_deg + std::abs(flight_.turn_bank_deg) + gust_.shake_deg +
                           2 * flight_.attitude_jitter_deg) +
                       half_diagonal;
    const double view_distance =
        flight_.view_distance_m > 0 ? flight_.view_distance_m : std::clamp(25.0 * flight_.altitude_m, 150.0, 400.0);
    reach = std::max(reach, far < Deg(85) ? max_altitude * std::tan(far) + 10.0 : view_distance);
  }
  min_xy_ -= Eigen::Vector2d::Constant(reach);
  max_xy_ += Eigen::Vector2d::Constant(reach);
}

void FlightPlan::PathAt(double s, Eigen::Vector2d* position, double* heading, double* turning) const {
  if (flight_.path == "road") {
    RoadAt(s, position, heading, turning);
  } else {
    SurveyAt(s, position, heading, turning);
  }
}

namespace {

// How far into a turn, 0 at its ends, 1 over its middle half: the bank rolls in and out.
double TurnWeight(double fraction) {
  return SmoothStep(fraction / 0.25) * SmoothStep((1.0 - fraction) / 0.25);
}

// An omega turn from a strip heading +x that ends at the origin to the strip `spacing` to its
// left heading back, on arcs of `radius` (over half the spacing): out to the right, around to
// the left, in to the right, each tangent to the next. Its centres: (0, -r), (h, spacing / 2),
// (0, spacing + r), the middle one 2r from the others.
struct OmegaTurn {
  OmegaTurn(double radius, double spacing) : r(radius), d(spacing) {
    h = std::sqrt(4 * r * r - (r + d / 2) * (r + d / 2));
    phi = std::atan2(r + d / 2, h);  // direction from the first centre to the middle one
    theta = M_PI / 2 - phi;          // how far the outer arcs turn
  }
  double Length() const { return r * (M_PI + 4 * theta); }
  // Position, heading and turning (signed TurnWeight, + left) `a` metres into the turn.
  void At(double a, Eigen::Vector2d* position, double* heading, double* turning) const {
    const double outer = r * theta, middle = r * (M_PI + 2 * theta);
    double angle;
    if (a < outer) {  // out, clockwise about (0, -r)
      angle = M_PI / 2 - a / r;
      *position = Eigen::Vector2d(0, -r) + r * Eigen::Vector2d(std::cos(angle), std::sin(angle));
      *heading = angle - M_PI / 2;
      *turning = -TurnWeight(a / outer);
    } else if (a < outer + middle) {  // around, anticlockwise about (h, d / 2)
      angle = phi + M_PI + (a - outer) / r;
      *position = Eigen::Vector2d(h, d / 2) + r * Eigen::Vector2d(std::cos(angle), std::sin(angle));
      *heading = angle + M_PI / 2;
      *turning = TurnWeight((a - outer) / middle);
    } else {  // in, clockwise about (0, d + r)
      const double c = std::min(a - outer - middle, outer);
      angle = -phi - c / r;
      *position = Eigen::Vector2d(0, d + r) + r * Eigen::Vector2d(std::cos(angle), std::sin(angle));
      *heading = angle - M_PI / 2;
      *turning = -TurnWeight(c / outer);
    }
  }
  double r, d, h, phi, theta;
};

}  // namespace

double FlightPlan::SurveyTurnLength() const {
  if (survey_turn_radius_ <= strip_spacing_ / 2) return M_PI * strip_spacing_ / 2;
  return OmegaTurn(survey_turn_radius_, strip_spacing_).Length();
}

void FlightPlan::SurveyAt(double s, Eigen::Vector2d* position, double* heading, double* turning) const {
  const double turn_length = SurveyTurnLength();
  const double period = flight_.strip_length_m + turn_length;
  int strip = std::min(static_cast<int>(s / period), flight_.num_strips - 1);
  double along = s - strip * period;
  const double direction = strip % 2 == 0 ? 1.0 : -1.0;
  const double strip_y = strip * strip_spacing_;
  const double start_x = strip % 2 == 0 ? 0.0 : flight_.strip_length_m;
  *turning = 0;
  if (along <= flight_.strip_length_m || strip == flight_.num_strips - 1) {
    *position = Eigen::Vector2d(start_x + direction * along, strip_y);
    *heading = direction > 0 ? 0.0 : M_PI;
    return;
  }
  // To the next strip: left on even strips, right on odd.
  const double end_x = start_x + direction * flight_.strip_length_m;
  if (survey_turn_radius_ > strip_spacing_ / 2) {
    // An omega turn, drawn heading +x and mirrored onto odd strips.
    Eigen::Vector2d local;
    double local_heading;
    OmegaTurn(survey_turn_radius_, strip_spacing_).At(along - flight_.strip_length_m, &local, &local_heading, turning);
    *position = Eigen::Vector2d(end_x + direction * local.x(), strip_y + local.y());
    *heading = direction > 0 ? local_heading : M_PI - local_heading;
    *turning *= direction;
    return;
  }
  // A half-turn centred at the strip's end.
  const double angle = (along - flight_.strip_length_m) / (strip_spacing_ / 2);  // 0 .. pi
  const double radius = strip_spacing_ / 2;
  const Eigen::Vector2d centre(end_x, strip_y + radius);
  *position = centre + radius * Eigen::Vector2d(direction * std::sin(angle), -std::cos(angle));
  *heading = direction > 0 ? angle : M_PI - angle;
  *turning = direction * TurnWeight(angle / M_PI);
}

void FlightPlan::RoadAt(double s, Eigen::Vector2d* position, double* heading, double* turning) const {
  const double radius = flight_.turn_radius_m;
  const double turn_length = M_PI / 2 * radius;
  Eigen::Vector2d start(0, 0);
  double direction = 0;  // heading of the current leg
  *turning = 0;
  for (int leg = 0;; ++leg) {
    const Eigen::Vector2d forward(std::cos(direction), std::sin(direction));
    if (s <= flight_.strip_length_m || leg == flight_.num_strips - 1) {
      *position = start + s * forward;
      *heading = direction;
      return;
    }
    s -= flight_.strip_length_m;
    // A quarter turn, left after even legs and right after odd ones.
    const double sign = leg % 2 == 0 ? 1.0 : -1.0;
    const Eigen::Vector2d end = start + flight_.strip_length_m * forward;
    const Eigen::Vector2d centre = end + sign * radius * Eigen::Vector2d(-forward.y(), forward.x());
    const auto rotate = [](const Eigen::Vector2d& v, double angle) {
      return Eigen::Vector2d(std::cos(angle) * v.x() - std::sin(angle) * v.y(),
                             std::sin(angle) * v.x() + std::cos(angle) * v.y());
    };
    if (s <= turn_length) {
      const double angle = s / radius;
      *position = centre + rotate(end - centre, sign * angle);
      *heading = direction + sign * angle;
      *turning = sign * TurnWeight(angle / (M_PI / 2));
      return;
    }
    s -= turn_length;
    start = centre + rotate(end - centre, sign * M_PI / 2);
    direction += sign * M_PI / 2;
  }
}

int64_t FlightPlan::TimestampNs(int frame) const {
  return static_cast<int64_t>(std::llround(frame * 1e9 / flight_.fps));
}

std::pair<double, double> FlightPlan::GustBlur(int frame) const {
  const auto& windows = gusts_.windows();
  for (size_t g = 0; g < windows.size(); ++g) {
    if (frame >= windows[g].start && frame < windows[g].end()) {
      Rng rng(HashU64(seed_, static_cast<uint64_t>(frame), 0xb1u));
      return {gust_.blur_px * blur_per_px_ * rng.Uniform(0.7, 1.0), rng.Uniform(0, M_PI)};
    }
  }
  return {0.0, 0.0};
}

}  // namespace stitch
