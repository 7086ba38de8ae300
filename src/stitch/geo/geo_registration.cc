#include "stitch/geo/geo_registration.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Eigenvalues>

#include "stitch/geometry/similarity.h"
#include "stitch/util/error.h"
#include "stitch/util/rng.h"
#include "stitch/util/statistics.h"

namespace stitch {

namespace {

constexpr int kRansacSamples = 500;
constexpr int kRefinements = 10;
// A map's cameras agree on which way is up when the mean of the up direction in their frames is
// at least this long (1: all alike; a camera tilted 25 degrees back and forth about it: 0.9).
constexpr double kLevelAgreement = 0.9;

// A fix and the camera where the map has it at the fix's time.
struct FixPair {
  int64_t t_ns = 0;
  Eigen::Vector3d centre;  // the camera's centre in the map's frame
  Eigen::Quaterniond map_from_cam;
  Eigen::Vector3d enu;
  double horizontal_sigma_m = 1.0;
  double vertical_sigma_m = 1.0;
};

// The fix's offset from where the placement puts the antenna, in ENU metres.
Eigen::Vector3d Residual(const Sim3d& enu_from_map, const FixPair& p, const Eigen::Vector3d& antenna_in_cam) {
  const Eigen::Vector3d antenna = enu_from_map * p.centre + enu_from_map.rotation * (p.map_from_cam * antenna_in_cam);
  return p.enu - antenna;
}

// The residual in the fix's stated sigmas, squared (three axes).
double NormalizedSquared(const Eigen::Vector3d& r, const FixPair& p) {
  const double h = p.horizontal_sigma_m, v = p.vertical_sigma_m;
  return (r.x() * r.x() + r.y() * r.y()) / (h * h) + r.z() * r.z() / (v * v);
}

// Least squares on `inliers`, the antenna's offset applied with the rotation of `guess`.
Sim3d Fit(const std::vector<FixPair>& pairs, const std::vector<int>& inliers, const Sim3d& guess,
          const Eigen::Vector3d& antenna_in_cam) {
  std::vector<Eigen::Vector3d> in_map, in_enu;
  for (int i : inliers) {
    in_map.push_back(pairs[i].centre);
    in_enu.push_back(pairs[i].enu - guess.rotation * (pairs[i].map_from_cam * antenna_in_cam));
  }
  return AlignPoints(in_map, in_enu, true);
}

// The pairs among `among` that agree with `enu_from_map`, and the truncated cost of all of them.
std::vector<int> Inliers(const std::vector<FixPair>& pairs, const std::vector<int>& among, const Sim3d& enu_from_map,
                         const Eigen::Vector3d& antenna_in_cam, double threshold_squared, double* cost) {
  std::vector<int> inliers;
  *cost = 0.0;
  for (int i : among) {
    const double d2 = NormalizedSquared(Residual(enu_from_map, pairs[i], antenna_in_cam), pairs[i]);
    if (d2 <= threshold_squared) {
      inliers.push_back(i);
      *cost += d2;
    } else {
      *cost += threshold_squared;
    }
  }
  return inliers;
}

struct PrincipalAxes {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  Eigen::Vector3d main = Eigen::Vector3d::UnitX();  // the direction of the largest spread
  double spread_across = 0.0;                       // standard deviation across it (the middle axis), metres
};

PrincipalAxes AxesOf(const std::vector<Eigen::Vector3d>& points) {
  PrincipalAxes axes;
  for (const auto& p : points) axes.mean += p;
  axes.mean /= static_cast<double>(points.size());
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  for (const auto& p : points) covariance += (p - axes.mean) * (p - axes.mean).transpose();
  covariance /= static_cast<double>(points.size());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(covariance);
  axes.main = solver.eigenvectors().col(2);  // ascending eigenvalues
  axes.spread_across = std::sqrt(std::max(0.0, solver.eigenvalues()(1)));
  return axes;
}

// The rotation taking `direction_a` to `direction_b` and `up_a` (projected off the direction) to
// `up_b` likewise.
Eigen::Quaterniond RotationFromTwoDirections(const Eigen::Vector3d& direction_a, const Eigen::Vector3d& up_a,
                                             const Eigen::Vector3d& direction_b, const Eigen::Vector3d& up_b) {
  const auto frame = [](const Eigen::Vector3d& d, const Eigen::Vector3d& up) {
    Eigen::Matrix3d m;
    m.col(0) = d.normalized();
    m.col(1) = (up - up.dot(m.col(0)) * m.col(0)).normalized();
    m.col(2) = m.col(0).cross(m.col(1));
    return m;
  };
  return Eigen::Quaterniond(frame(direction_b, up_b) * frame(direction_a, up_a).transpose()).normalized();
}

// Along a line: the rotation from the line's direction in both frames and the map's up; the scale
// and translation by least squares. `indices` of two pairs: the line through them.
Sim3d FitAlongLine(const std::vector<FixPair>& pairs, const std::vector<int>& indices, const Sim3d& guess,
                   const Eigen::Vector3d& antenna_in_cam, const Eigen::Vector3d& up_in_map) {
  std::vector<Eigen::Vector3d> in_map, in_enu;
  for (int i : indices) {
    in_map.push_back(pairs[i].centre);
    in_enu.push_back(pairs[i].enu - guess.rotation * (pairs[i].map_from_cam * antenna_in_cam));
  }
  const PrincipalAxes axes_map = AxesOf(in_map), axes_enu = AxesOf(in_enu);
  const Eigen::Vector3d& mean_map = axes_map.mean;
  const Eigen::Vector3d& mean_enu = axes_enu.mean;
  // Two pairs: the line through them; more: their main direction.
  Eigen::Vector3d direction_map = indices.size() == 2 ? Eigen::Vector3d(in_map[1] - in_map[0]) : axes_map.main;
  Eigen::Vector3d direction_enu = indices.size() == 2 ? Eigen::Vector3d(in_enu[1] - in_enu[0]) : axes_enu.main;
  double agreement = 0.0;
  for (size_t i = 0; i < in_map.size(); ++i) {
    agreement += (in_map[i] - mean_map).dot(direction_map) * (in_enu[i] - mean_enu).dot(direction_enu);
  }
  if (agreement < 0) direction_enu = -direction_enu;
  if (direction_map.norm() < 1e-12 || direction_enu.norm() < 1e-12) throw Error("no direction");
  Sim3d fit;
  fit.rotation = RotationFromTwoDirections(direction_map, up_in_map, direction_enu, Eigen::Vector3d::UnitZ());
  double along = 0.0, squared = 0.0;
  for (size_t i = 0; i < in_map.size(); ++i) {
    along += (fit.rotation * (in_map[i] - mean_map)).dot(in_enu[i] - mean_enu);
    squared += (in_map[i] - mean_map).squaredNorm();
  }
  if (!(squared > 0) || !(along > 0)) throw Error("no scale");
  fit.scale = along / squared;
  fit.translation = mean_enu - fit.scale * (fit.rotation * mean_map);
  return fit;
}

}  // namespace

bool GeoReferenceOptions::Check(std::string* why) const {
  if (min_fixes < 3) return *why = "min_fixes must be at least 3", false;
  if (!(min_spread_m >= 0)) return *why = "min_spread_m must not be negative", false;
  if (camera_up_axis != "auto" && camera_up_axis != "-z" && camera_up_axis != "-y" && camera_up_axis != "none") {
    return *why = "camera_up_axis must be auto, -z, -y or none", false;
  }
  if (level_by_camera != "auto" && level_by_camera != "true" && level_by_camera != "false") {
    return *why = "level_by_camera must be auto, true or false", false;
  }
  if (!(max_interpolation_gap_s > 0)) return *why = "max_interpolation_gap_s must be positive", false;
  if (!(outlier_chi2 > 0)) return *why = "outlier_chi2 must be positive", false;
  if (!(min_inlier_fraction > 0 && min_inlier_fraction <= 1)) {
    return *why = "min_inlier_fraction must be in (0, 1]", false;
  }
  for (double a : {antenna_x_m, antenna_y_m, antenna_z_m}) {
    if (!(std::abs(a) <= 10.0)) return *why = "the antenna's offset from the camera must be within 10 m", false;
  }
  if (!(std::abs(time_offset_s) <= 3600.0)) return *why = "time_offset_s must be within an hour", false;
  return true;
}

GeoPlacement PlaceByGnss(const Trajectory& map_poses, const std::vector<EnuFix>& fixes,
                         const GeoReferenceOptions& options,
                         const std::optional<Eigen::Vector3d>& learned_up_in_camera) {
  GeoPlacement placement;
  const Eigen::Vector3d antenna(options.antenna_x_m, options.antenna_y_m, options.antenna_z_m);
  const auto max_gap_ns = static_cast<int64_t>(options.max_interpolation_gap_s * 1e9);
  const auto offset_ns = static_cast<int64_t>(std::llround(options.time_offset_s * 1e9));

  std::vector<FixPair> pairs;
  for (const EnuFix& f : fixes) {
    const std::optional<Rigid3d> pose = map_poses.PoseAt(f.t_ns + offset_ns, max_gap_ns);
    if (!pose) continue;
    pairs.push_back({f.t_ns, pose->translation, pose->rotation, f.enu, f.horizontal_sigma_m, f.vertical_sigma_m});
  }
  placement.fixes_matched = static_cast<int>(pairs.size());
  if (placement.fixes_matched < options.min_fixes) {
    placement.why_not = Str() << placement.fixes_matched << " fixes within its frames (needs " << options.min_fixes
                              << ")";
    return placement;
  }
  std::vector<Eigen::Vector3d> fix_positions;
  std::vector<double> sigmas;
  for (const FixPair& p : pairs) {
    fix_positions.push_back(p.enu);
    sigmas.push_back(p.horizontal_sigma_m);
  }
  const double median_sigma = Median(sigmas);
  placement.spread_m = AxesOf(fix_positions).spread_across;
  const double spread_needed = std::max(options.min_spread_m, 5.0 * median_sigma);
  // Along a line: the rotation about it from the cameras' mean up direction, where they agree on one.
  const bool along_line = placement.spread_m < spread_needed;
  Eigen::Vector3d up_in_map = Eigen::Vector3d::Zero();
  if (along_line) {
    char text[240];
    if (options.camera_up_axis == "none") {
      std::snprintf(text, sizeof(text),
                    "its fixes lie along a line (%.1f m across it, needs %.1f m): the rotation about it is not known "
                    "(georeference.camera_up_axis is none)",
                    placement.spread_m, spread_needed);
      placement.why_not = text;
      return placement;
    }
    const bool learned = options.camera_up_axis == "auto" && learned_up_in_camera;
    const Eigen::Vector3d up_in_cam = learned                          ? learned_up_in_camera->normalized()
                                      : options.camera_up_axis == "-y" ? -Eigen::Vector3d::UnitY()
                                                                       : -Eigen::Vector3d::UnitZ();
    const std::string axis = learned ? "learned up" : options.camera_up_axis == "-y" ? "-y" : "-z";
    for (const FixPair& p : pairs) up_in_map += p.map_from_cam * up_in_cam;
    up_in_map /= static_cast<double>(pairs.size());
    std::vector<Eigen::Vector3d> centres;
    for (const FixPair& p : pairs) centres.push_back(p.centre);
    const double along_up = std::abs(up_in_map.normalized().dot(AxesOf(centres).main));
    if (up_in_map.norm() < 0.5 || along_up > 0.9) {
      std::snprintf(text, sizeof(text),
                    "its fixes lie along a line (%.1f m across it, needs %.1f m) and its cameras do not say which way "
                    "is up about it (their %s axes agree to %.2f, %.2f along the line)",
                    placement.spread_m, spread_needed, axis.c_str(), up_in_map.norm(), along_up);
      placement.why_not = text;
      return placement;
    }
    up_in_map.normalize();
  }
  placement.method = along_line ? (options.camera_up_axis == "auto" && learned_up_in_camera ? "gnss+learned-camera-up"
                                                                                            : "gnss+camera-up")
                                : "gnss";
  const auto fit = [&](const std::vector<int>& indices, const Sim3d& guess, const Eigen::Vector3d& antenna_in_cam) {
    return along_line ? FitAlongLine(pairs, indices, guess, antenna_in_cam, up_in_map)
                      : Fit(pairs, indices, guess, antenna_in_cam);
  };

  // RANSAC over triples (pairs along a line) of the fixes `among`; a triple whose cameras lie on a
  // line is skipped. Then least squares on the inliers until they stay the same.
  const int n = static_cast<int>(pairs.size());
  const auto consensus = [&](const std::vector<int>& among, std::vector<int>* best_inliers) {
    Rng rng(0x6E55F1A5ULL ^ static_cast<uint64_t>(among.size()));
    const int m = static_cast<int>(among.size());
    Sim3d best;
    best_inliers->clear();
    double best_cost = 0.0;
    for (int sample = 0; sample < kRansacSamples && m >= 3; ++sample) {
      const int a = among[rng.UniformInt(0, m - 1)], b = among[rng.UniformInt(0, m - 1)],
                c = among[rng.UniformInt(0, m - 1)];
      std::vector<int> minimal;
      if (along_line) {
        if (a == b) continue;
        minimal = {a, b};
      } else {
        if (a == b || b == c || a == c) continue;
        const Eigen::Vector3d ab = pairs[b].centre - pairs[a].centre, ac = pairs[c].centre - pairs[a].centre;
        if (ab.cross(ac).norm() < 1e-3 * ab.norm() * ac.norm()) continue;
        minimal = {a, b, c};
      }
      Sim3d guess;
      try {
        // Once without the antenna's offset, to know the rotation, then with it.
        guess = fit(minimal, Sim3d(), Eigen::Vector3d::Zero());
        if (!antenna.isZero()) guess = fit(minimal, guess, antenna);
      } catch (const Error&) {
        continue;
      }
      if (!(guess.scale > 0) || !std::isfinite(guess.scale)) continue;
      double cost = 0.0;
      std::vector<int> inliers = Inliers(pairs, among, guess, antenna, options.outlier_chi2, &cost);
      if (inliers.size() > best_inliers->size() || (inliers.size() == best_inliers->size() && cost < best_cost)) {
        best = guess;
        *best_inliers = std::move(inliers);
        best_cost = cost;
      }
    }
    for (int round = 0; round < kRefinements && best_inliers->size() >= 3; ++round) {
      Sim3d refined;
      try {
        refined = fit(*best_inliers, best, antenna);
      } catch (const Error&) {
        break;
      }
      double cost = 0.0;
      std::vector<int> inliers = Inliers(pairs, among, refined, antenna, options.outlier_chi2, &cost);
      const bool same = inliers == *best_inliers;
      best = refined;
      if (inliers.size() < 3) break;
      *best_inliers = std::move(inliers);
      if (same) break;
    }
    return best;
  };
  std::vector<int> everyone(n), best_inliers;
  for (int i = 0; i < n; ++i) everyone[i] = i;
  Sim3d best = consensus(everyone, &best_inliers);
  if (best_inliers.size() < 3) {
    placement.why_not = "no three of its fixes agree with one placement";
    return placement;
  }
  // Do enough of the rest agree on another placement (a receiver that jumped for good, or was
  // spoofed)? Then that group is reported, and the map is held where the group that came first
  // puts it, unless the other holds more than twice its fixes.
  int disagreeing = 0;
  {
    std::vector<bool> taken(n, false);
    for (int i : best_inliers) taken[i] = true;
    std::vector<int> rest;
    for (int i = 0; i < n; ++i) {
      if (!taken[i]) rest.push_back(i);
    }
    const int group_needed = std::max(options.min_fixes, n / 5);
    std::vector<int> group;
    Sim3d other;
    if (static_cast<int>(rest.size()) >= group_needed) other = consensus(rest, &group);
    if (static_cast<int>(group.size()) >= group_needed) {
      const bool other_first = pairs[group.front()].t_ns < pairs[best_inliers.front()].t_ns;
      if (other_first && group.size() * 2 >= best_inliers.size()) {
        std::swap(best, other);
        std::swap(best_inliers, group);
      }
      GeoPlacement::Disagreement d;
      d.fixes = static_cast<int>(group.size());
      d.first_ns = pairs[group.front()].t_ns;
      d.last_ns = pairs[group.back()].t_ns;
      std::vector<double> apart;
      for (int i = 0; i < n; ++i) apart.push_back((other * pairs[i].centre - best * pairs[i].centre).norm());
      d.apart_m = Median(apart);
      placement.disagreement = d;
      disagreeing = d.fixes;
    }
  }
  // A stated mount levels the map: turned about its inliers' centre (which stays where the fixes
  // put it) so that the cameras' mean up axis points up.
  if (!along_line && options.LevelsByCamera() && (options.camera_up_axis == "-z" || options.camera_up_axis == "-y")) {
    const Eigen::Vector3d up_in_cam = options.camera_up_axis == "-y" ? Eigen::Vector3d(-Eigen::Vector3d::UnitY())
                                                                     : Eigen::Vector3d(-Eigen::Vector3d::UnitZ());
    Eigen::Vector3d up = Eigen::Vector3d::Zero(), centre = Eigen::Vector3d::Zero();
    for (int i : best_inliers) {
      up += best.rotation * (pairs[i].map_from_cam * up_in_cam);
      centre += pairs[i].centre;
    }
    centre /= static_cast<double>(best_inliers.size());
    // Only cameras that agree on an up direction say one.
    if (up.norm() > 0.5 * static_cast<double>(best_inliers.size())) {
      const Eigen::Vector3d at = best * centre;
      best.rotation =
          (Eigen::Quaterniond::FromTwoVectors(up.normalized(), Eigen::Vector3d::UnitZ()) * best.rotation).normalized();
      best.translation = at - best.scale * (best.rotation * centre);
      placement.method += "+level";
    }
  }
  placement.enu_from_map = best;
  placement.inliers = static_cast<int>(best_inliers.size());
  double horizontal = 0.0, vertical = 0.0;
  std::vector<bool> inlier(pairs.size(), false);
  for (int i : best_inliers) {
    inlier[i] = true;
    const Eigen::Vector3d r = Residual(best, pairs[i], antenna);
    horizontal += r.x() * r.x() + r.y() * r.y();
    vertical += r.z() * r.z();
  }
  placement.horizontal_rms_m = std::sqrt(horizontal / placement.inliers);
  placement.vertical_rms_m = std::sqrt(vertical / placement.inliers);
  for (int i = 0; i < n; ++i) {
    if (inlier[i]) continue;
    if (i > 0 && !inlier[i - 1] && !placement.outlier_spans.empty()) {
      placement.outlier_spans.back().second = pairs[i].t_ns;
    } else {
      placement.outlier_spans.push_back({pairs[i].t_ns, pairs[i].t_ns});
    }
  }
  // Of the fixes but a disagreeing group, enough must agree.
  if (placement.inliers < options.min_inlier_fraction * (n - disagreeing)) {
    char text[160];
    std::snprintf(text, sizeof(text), "only %d of its %d fixes agree with one placement (needs %.0f%%)",
                  placement.inliers, n - disagreeing, 100.0 * options.min_inlier_fraction);
    placement.why_not = text;
    return placement;
  }
  placement.placed = true;
  if (!along_line) {
    // ENU's up in each inlier's camera frame; kept where they agree (a camera that flew level).
    Eigen::Vector3d up = Eigen::Vector3d::Zero();
    for (int i : best_inliers) {
      up += (best.rotation * pairs[i].map_from_cam).inverse() * Eigen::Vector3d::UnitZ();
    }
    up /= static_cast<double>(best_inliers.size());
    if (up.norm() > kLevelAgreement) placement.up_in_camera = up.normalized();
  }
  return placement;
}

std::vector<GeoPlacement> PlaceMapsByGnss(const std::vector<MapToPlace>& maps, const GeoReferenceOptions& options) {
  std::vector<GeoPlacement> placements;
  for (const MapToPlace& map : maps) placements.push_back(PlaceByGnss(*map.poses, *map.fixes, options));
  if (options.camera_up_axis != "auto") return placements;
  const GeoPlacement* teacher = nullptr;
  for (const GeoPlacement& p : placements) {
    if (p.up_in_camera && (!teacher || p.inliers > teacher->inliers)) teacher = &p;
  }
  if (!teacher) return placements;
  const Eigen::Vector3d up = *teacher->up_in_camera;
  for (size_t i = 0; i < maps.size(); ++i) {
    // A map placed by its fixes alone keeps its placement; one along a line takes the learned up.
    if (placements[i].placed && placements[i].method == "gnss") continue;
    GeoPlacement again = PlaceByGnss(*maps[i].poses, *maps[i].fixes, options, up);
    if (again.placed || !placements[i].placed) placements[i] = std::move(again);
  }
  return placements;
}

}  // namespace stitch
