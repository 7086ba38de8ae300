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
  if (!(altitude_m >= 5 && altitude_m <= 5000)) return fail("flight.altitude_m must be in [5, 5000]");
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
    : flight_(flight), gust_(gust), gusts_(gusts), seed_(seed) {
  CheckOptions(flight_, "synthetic.flight");
  CheckOptions(gust_, "synthetic.gust");
  // Image x runs across the track, so the footprint width across the track is width * h / fx.
  const double footprint_across = camera.width() * flight_.altitude_m / camera.fx();
  const double footprint_along = camera.height() * flight_.altitude_m / camera.fy();
  strip_spacing_ = (1.0 - flight_.side_overlap) * footprint_across;
  path_length_ = flight_.num_strips * flight_.strip_length_m + (flight_.num_strips - 1) * M_PI * strip_spacing_ / 2;

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
    double heading;
    PathAt(path_length_ * i / (flight_.num_frames - 1), &position, &heading);
    double altitude = flight_.altitude_m + flight_.altitude_jitter_m * std::sin(2 * M_PI * frequency[0] * t + phase[0]);
    double roll = Deg(flight_.attitude_jitter_deg) * std::sin(2 * M_PI * frequency[1] * t + phase[1]) +
                  0.5 * Deg(flight_.attitude_jitter_deg) * std::sin(2 * M_PI * frequency[2] * t + phase[2]);
    double pitch = Deg(flight_.attitude_jitter_deg) * std::sin(2 * M_PI * frequency[3] * t + phase[3]) +
                   0.5 * Deg(flight_.attitude_jitter_deg) * std::sin(2 * M_PI * frequency[4] * t + phase[4]);
    double yaw = heading;
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
    // (y_cam = -x_body), image right to the right (x_cam = -y_body).
    const Eigen::Quaterniond world_from_body = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
                                               Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
                                               Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX());
    Eigen::Matrix3d body_from_cam;
    body_from_cam.col(0) = -Eigen::Vector3d::UnitY();
    body_from_cam.col(1) = -Eigen::Vector3d::UnitX();
    body_from_cam.col(2) = -Eigen::Vector3d::UnitZ();
    const Eigen::Quaterniond world_from_cam = (world_from_body * Eigen::Quaterniond(body_from_cam)).normalized();
    poses_.emplace_back(world_from_cam, Eigen::Vector3d(position.x(), position.y(), altitude));
    min_xy_ = min_xy_.cwiseMin(position);
    max_xy_ = max_xy_.cwiseMax(position);
    max_altitude = std::max(max_altitude, altitude);
  }
  // Ground the camera may see: half the footprint diagonal at the highest altitude, with room
  // for the attitude (shaking tilts the view).
  const double reach = 0.5 * std::hypot(footprint_across, footprint_along) * max_altitude / flight_.altitude_m +
                       max_altitude * std::tan(Deg(gust_.shake_deg + 2 * flight_.attitude_jitter_deg)) + 10.0;
  min_xy_ -= Eigen::Vector2d::Constant(reach);
  max_xy_ += Eigen::Vector2d::Constant(reach);
}

void FlightPlan::PathAt(double s, Eigen::Vector2d* position, double* heading) const {
  const double turn_length = M_PI * strip_spacing_ / 2;
  const double period = flight_.strip_length_m + turn_length;
  int strip = std::min(static_cast<int>(s / period), flight_.num_strips - 1);
  double along = s - strip * period;
  const double direction = strip % 2 == 0 ? 1.0 : -1.0;
  const double strip_y = strip * strip_spacing_;
  const double start_x = strip % 2 == 0 ? 0.0 : flight_.strip_length_m;
  if (along <= flight_.strip_length_m || strip == flight_.num_strips - 1) {
    *position = Eigen::Vector2d(start_x + direction * along, strip_y);
    *heading = direction > 0 ? 0.0 : M_PI;
    return;
  }
  // Half-turn to the next strip, centred at the strip's end.
  const double angle = (along - flight_.strip_length_m) / (strip_spacing_ / 2);  // 0 .. pi
  const double radius = strip_spacing_ / 2;
  const double end_x = start_x + direction * flight_.strip_length_m;
  const Eigen::Vector2d centre(end_x, strip_y + radius);
  *position = centre + radius * Eigen::Vector2d(direction * std::sin(angle), -std::cos(angle));
  *heading = direction > 0 ? angle : M_PI - angle;
}

int64_t FlightPlan::TimestampNs(int frame) const {
  return static_cast<int64_t>(std::llround(frame * 1e9 / flight_.fps));
}

std::pair<double, double> FlightPlan::GustBlur(int frame) const {
  const auto& windows = gusts_.windows();
  for (size_t g = 0; g < windows.size(); ++g) {
    if (frame >= windows[g].start && frame < windows[g].end()) {
      Rng rng(HashU64(seed_, static_cast<uint64_t>(frame), 0xb1u));
      return {gust_.blur_px * rng.Uniform(0.7, 1.0), rng.Uniform(0, M_PI)};
    }
  }
  return {0.0, 0.0};
}

}  // namespace stitch
