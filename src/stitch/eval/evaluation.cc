#include "stitch/eval/evaluation.h"

#include <algorithm>
#include <climits>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include <Eigen/Eigenvalues>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "stitch/geometry/similarity.h"
#include "stitch/io/image_file.h"
#include "stitch/util/error.h"
#include "stitch/util/ids.h"
#include "stitch/util/text_file.h"

namespace stitch {
namespace {

double Percentile(std::vector<double> values, double p) {
  std::sort(values.begin(), values.end());
  const double rank = p * (values.size() - 1);
  const size_t lo = static_cast<size_t>(std::floor(rank));
  const size_t hi = std::min(lo + 1, values.size() - 1);
  return values[lo] + (rank - lo) * (values[hi] - values[lo]);
}

double Rms(const std::vector<double>& values) {
  double sum = 0;
  for (double v : values) sum += v * v;
  return values.empty() ? 0 : std::sqrt(sum / values.size());
}

std::vector<StampedPose> ToStamped(const std::vector<PoseRecord>& poses) {
  std::vector<StampedPose> stamped;
  for (const auto& p : poses) stamped.push_back({p.t_ns, p.world_from_cam});
  return stamped;
}

}  // namespace

std::optional<TrajectoryErrors> CompareTrajectories(const std::vector<StampedPose>& estimated,
                                                    const Trajectory& ground_truth, int64_t max_association_gap_ns,
                                                    const std::optional<Sim3d>& alignment) {
  std::vector<Eigen::Vector3d> estimate_positions, truth_positions;
  std::vector<Rigid3d> estimate_poses, truth_poses;
  for (const auto& pose : estimated) {
    const auto truth = ground_truth.PoseAt(pose.t_ns, max_association_gap_ns);
    if (!truth) continue;
    estimate_positions.push_back(pose.world_from_cam.translation);
    truth_positions.push_back(truth->translation);
    estimate_poses.push_back(pose.world_from_cam);
    truth_poses.push_back(*truth);
  }
  if (estimate_positions.size() < 3) return std::nullopt;
  TrajectoryErrors errors;
  try {
    errors.ground_truth_from_estimate = alignment ? *alignment : AlignPoints(estimate_positions, truth_positions, true);
  } catch (const Error&) {
    return std::nullopt;  // collinear or coincident positions: no unique alignment
  }
  errors.pairs = static_cast<int>(estimate_positions.size());
  const Sim3d& align = errors.ground_truth_from_estimate;
  std::vector<double> ate;
  for (size_t i = 0; i < estimate_positions.size(); ++i) {
    ate.push_back((align * estimate_positions[i] - truth_positions[i]).norm());
  }
  errors.ate_rmse_m = Rms(ate);
  errors.ate_median_m = Percentile(ate, 0.5);
  errors.ate_max_m = *std::max_element(ate.begin(), ate.end());
  // RPE between consecutive posed frames, the estimate brought to ground-truth scale.
  std::vector<double> rpe_t, rpe_r;
  for (size_t i = 0; i + 1 < estimate_poses.size(); ++i) {
    const Rigid3d est_rel = estimate_poses[i].Inverse() * estimate_poses[i + 1];
    const Rigid3d gt_rel = truth_poses[i].Inverse() * truth_poses[i + 1];
    const Rigid3d est_scaled(est_rel.rotation, est_rel.translation * align.scale);
    const Rigid3d error = gt_rel.Inverse() * est_scaled;
    rpe_t.push_back(error.translation.norm());
    rpe_r.push_back(RotationAngle(error.rotation) * 180.0 / M_PI);
  }
  errors.rpe_translation_rmse_m = Rms(rpe_t);
  errors.rpe_rotation_rmse_deg = Rms(rpe_r);
  return errors;
}

Evaluation Evaluate(const EvaluationInput& input) {
  Evaluation e;
  e.frames_total = input.frames_total;
  e.frames_unusable = input.frames_unusable;
  e.frames_unreadable = input.frames_unreadable;
  e.frames_dropped = input.frames_dropped;
  e.frames_late_at_source = input.frames_late_at_source;
  e.keyframes = input.keyframes;
  e.submaps = input.submaps;
  e.has_ground_truth = !input.ground_truth.empty();

  // The largest merged map: the component holding the most posed frames.
  std::map<int, int> frames_per_component;
  std::map<int, std::set<int64_t>> submaps_per_component;
  for (const auto& p : input.poses) {
    ++frames_per_component[p.component];
    submaps_per_component[p.component].insert(p.submap_id);
  }
  for (const auto& [component, count] : frames_per_component) {
    if (count > e.frames_localized) {
      e.frames_localized = count;
      e.largest_component = component;
    }
  }
  e.submaps_merged = e.largest_component >= 0 ? static_cast<int>(submaps_per_component[e.largest_component].size()) : 0;
  e.completeness = e.frames_total > 0 ? static_cast<double>(e.frames_localized) / e.frames_total : 0.0;

  if (e.has_ground_truth && e.largest_component >= 0) {
    std::vector<PoseRecord> largest;
    for (const auto& p : input.poses) {
      if (p.component == e.largest_component) largest.push_back(p);
    }
    e.errors = CompareTrajectories(ToStamped(largest), input.ground_truth, input.max_association_gap_ns);
    // The path the largest map flew, for ATE as a share of it (the real-time issue's 0.3%).
    std::sort(largest.begin(), largest.end(), [](const PoseRecord& a, const PoseRecord& b) { return a.t_ns < b.t_ns; });
    std::optional<Eigen::Vector3d> previous;
    for (const auto& p : largest) {
      const auto truth = input.ground_truth.PoseAt(p.t_ns, input.max_association_gap_ns);
      if (!truth) continue;
      if (previous) e.ground_truth_path_m += (truth->translation - *previous).norm();
      previous = truth->translation;
    }
  }
  if (e.has_ground_truth) {
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e18), hi = -lo;
    for (const auto& p : input.poses) {
      if (const auto truth = input.ground_truth.PoseAt(p.t_ns, input.max_association_gap_ns)) {
        lo = lo.cwiseMin(truth->translation);
        hi = hi.cwiseMax(truth->translation);
      }
    }
    if (lo.x() <= hi.x()) e.ground_truth_extent_m = (hi - lo).norm();
  }
  std::map<int64_t, std::vector<PoseRecord>> by_submap;
  for (const auto& p : input.poses) by_submap[p.submap_id].push_back(p);
  // The largest map's parts that views join, each aligned on its own, where GNSS junctions join them.
  const auto part_of = [&](int64_t submap) {
    const auto found = input.view_part.find(submap);
    return found != input.view_part.end() ? found->second : submap;
  };
  std::map<int64_t, Sim3d> part_alignment;
  if (e.errors && !input.view_part.empty()) {
    std::map<int64_t, std::vector<PoseRecord>> parts;
    for (const auto& p : input.poses) {
      if (p.component == e.largest_component) parts[part_of(p.submap_id)].push_back(p);
    }
    if (parts.size() > 1) {
      for (const auto& [part, poses] : parts) {
        const auto own = CompareTrajectories(ToStamped(poses), input.ground_truth, input.max_association_gap_ns);
        if (own) part_alignment[part] = own->ground_truth_from_estimate;
      }
    }
  }
  for (const auto& [submap, poses] : by_submap) {
    SubmapEvaluation s;
    s.submap_id = submap;
    s.component = poses.front().component;
    s.frames = static_cast<int>(poses.size());
    for (const auto& p : poses) {
      if (input.ground_truth.PoseAt(p.t_ns, input.max_association_gap_ns)) ++s.frames_with_ground_truth;
    }
    if (e.has_ground_truth) {
      const auto own = CompareTrajectories(ToStamped(poses), input.ground_truth, input.max_association_gap_ns);
      if (own) s.ate_rmse_m = own->ate_rmse_m;
      if (e.errors && s.component == e.largest_component) {
        const auto rms_under = [&](const Sim3d& alignment) -> std::optional<double> {
          std::vector<double> errors;
          for (const auto& p : poses) {
            if (const auto truth = input.ground_truth.PoseAt(p.t_ns, input.max_association_gap_ns)) {
              errors.push_back((alignment * p.world_from_cam.translation - truth->translation).norm());
            }
          }
          return errors.empty() ? std::nullopt : std::optional<double>(Rms(errors));
        };
        s.ate_in_map_m = rms_under(e.errors->ground_truth_from_estimate);
        if (const auto part = part_alignment.find(part_of(submap)); part != part_alignment.end()) {
          s.ate_in_part_m = rms_under(part->second);
        }
      }
    }
    const std::optional<double> merged = s.ate_in_part_m ? s.ate_in_part_m : s.ate_in_map_m;
    s.wrong_merge =
        s.ate_rmse_m && merged && *merged > 3.0 * *s.ate_rmse_m && *merged > 0.005 * e.ground_truth_extent_m;
    e.wrong_merges += s.wrong_merge;
    e.per_submap.push_back(s);
  }
  if (!input.tracking_ms.empty()) {
    e.tracking_ms_median = Percentile(input.tracking_ms, 0.5);
    e.tracking_ms_p95 = Percentile(input.tracking_ms, 0.95);
  }
  return e;
}

nlohmann::json ToJson(const Evaluation& e) {
  using nlohmann::json;
  const auto optional = [](const std::optional<double>& v) { return v ? json(*v) : json(nullptr); };
  json j;
  j["frames_total"] = e.frames_total;
  j["frames_unusable"] = e.frames_unusable;
  j["frames_unreadable"] = e.frames_unreadable;
  j["frames_dropped"] = e.frames_dropped;
  j["frames_late_at_source"] = e.frames_late_at_source;
  j["frames_localized"] = e.frames_localized;
  j["completeness"] = e.completeness;
  j["keyframes"] = e.keyframes;
  j["submaps"] = e.submaps;
  j["submaps_merged"] = e.submaps_merged;
  j["gnss_junctions"] = e.gnss_junctions;
  j["has_ground_truth"] = e.has_ground_truth;
  j["ate_rmse_m"] = e.errors ? json(e.errors->ate_rmse_m) : json(nullptr);
  j["ate_median_m"] = e.errors ? json(e.errors->ate_median_m) : json(nullptr);
  j["ate_max_m"] = e.errors ? json(e.errors->ate_max_m) : json(nullptr);
  j["rpe_translation_rmse_m"] = e.errors ? json(e.errors->rpe_translation_rmse_m) : json(nullptr);
  j["rpe_rotation_rmse_deg"] = e.errors ? json(e.errors->rpe_rotation_rmse_deg) : json(nullptr);
  j["frames_with_ground_truth"] = e.errors ? e.errors->pairs : 0;
  if (e.errors) j["alignment_scale"] = e.errors->ground_truth_from_estimate.scale;
  j["ground_truth_extent_m"] = e.ground_truth_extent_m;
  j["ground_truth_path_m"] = e.ground_truth_path_m;
  j["wrong_merges"] = e.wrong_merges;
  j["tracking_ms_median"] = optional(e.tracking_ms_median);
  j["tracking_ms_p95"] = optional(e.tracking_ms_p95);
  json submaps = json::array();
  for (const auto& s : e.per_submap) {
    submaps.push_back({{"submap_id", s.submap_id},
                       {"component", s.component},
                       {"frames", s.frames},
                       {"frames_with_ground_truth", s.frames_with_ground_truth},
                       {"ate_rmse_m", optional(s.ate_rmse_m)},
                       {"ate_in_map_m", optional(s.ate_in_map_m)},
                       {"ate_in_part_m", optional(s.ate_in_part_m)},
                       {"wrong_merge", s.wrong_merge}});
  }
  j["per_submap"] = submaps;
  return j;
}

Evaluation EvaluationFromJson(const nlohmann::json& j) {
  const auto optional = [](const nlohmann::json& v) { return v.is_null() ? std::optional<double>() : v.get<double>(); };
  try {
    Evaluation e;
    e.frames_total = j.at("frames_total");
    e.frames_unusable = j.at("frames_unusable");
    e.frames_unreadable = j.value("frames_unreadable", 0);  // reports before they were counted
    e.frames_dropped = j.value("frames_dropped", 0);
    e.frames_late_at_source = j.value("frames_late_at_source", 0);
    e.frames_localized = j.at("frames_localized");
    e.completeness = j.at("completeness");
    e.keyframes = j.at("keyframes");
    e.submaps = j.at("submaps");
    e.submaps_merged = j.at("submaps_merged");
    e.gnss_junctions = j.value("gnss_junctions", 0);
    e.has_ground_truth = j.at("has_ground_truth");
    if (!j.at("ate_rmse_m").is_null()) {
      TrajectoryErrors errors;
      errors.ate_rmse_m = j.at("ate_rmse_m");
      errors.ate_median_m = j.at("ate_median_m");
      errors.ate_max_m = j.at("ate_max_m");
      errors.rpe_translation_rmse_m = j.at("rpe_translation_rmse_m");
      errors.rpe_rotation_rmse_deg = j.at("rpe_rotation_rmse_deg");
      errors.pairs = j.at("frames_with_ground_truth");
      errors.ground_truth_from_estimate.scale = j.value("alignment_scale", 1.0);
      e.errors = errors;
    }
    e.ground_truth_extent_m = j.value("ground_truth_extent_m", 0.0);
    e.ground_truth_path_m = j.value("ground_truth_path_m", 0.0);  // reports before it was measured: 0
    e.wrong_merges = j.value("wrong_merges", 0);
    e.tracking_ms_median = optional(j.at("tracking_ms_median"));
    e.tracking_ms_p95 = optional(j.at("tracking_ms_p95"));
    for (const auto& s : j.at("per_submap")) {
      SubmapEvaluation submap;
      submap.submap_id = s.at("submap_id");
      submap.component = s.at("component");
      submap.frames = s.at("frames");
      submap.frames_with_ground_truth = s.at("frames_with_ground_truth");
      submap.ate_rmse_m = optional(s.at("ate_rmse_m"));
      submap.ate_in_map_m = optional(s.at("ate_in_map_m"));
      if (s.contains("ate_in_part_m")) submap.ate_in_part_m = optional(s.at("ate_in_part_m"));
      submap.wrong_merge = s.value("wrong_merge", false);
      e.per_submap.push_back(submap);
    }
    return e;
  } catch (const nlohmann::json::exception& error) {
    throw Error(std::string("report: ") + error.what());
  }
}

Evaluation ReadReport(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw Error(path + ": cannot open (is it a finished run folder?)");
  try {
    return EvaluationFromJson(nlohmann::json::parse(in));
  } catch (const nlohmann::json::parse_error& error) {
    throw Error(path + ": not valid JSON (" + error.what() + ")");
  } catch (const Error& error) {
    throw Error(path + ": " + error.what());
  }
}

void WriteReport(const std::string& path, const Evaluation& evaluation, const nlohmann::json& run,
                 const nlohmann::json& merges, const nlohmann::json& georeference) {
  nlohmann::json report = ToJson(evaluation);
  if (!run.is_null()) report["run"] = run;
  if (!merges.is_null()) report["merges"] = merges;
  if (!georeference.is_null()) report["georeference"] = georeference;
  WriteFileAtomically(path, report.dump(2) + "\n");
}

namespace {

// The error lines of a summary: ATE, the path it is a share of, RPE.
std::string ErrorLines(const Evaluation& e) {
  char line[256];
  std::string text;
  if (e.errors) {
    std::snprintf(line, sizeof(line),
                  "  ATE RMSE          %.4f m over %d frames (Sim3-aligned; median %.4f, max %.4f)\n",
                  e.errors->ate_rmse_m, e.errors->pairs, e.errors->ate_median_m, e.errors->ate_max_m);
  } else if (e.has_ground_truth) {
    std::snprintf(line, sizeof(line), "  ATE RMSE          n/a (fewer than 3 posed frames with ground truth)\n");
  } else {
    std::snprintf(line, sizeof(line), "  ATE RMSE          n/a (no ground truth)\n");
  }
  text += line;
  if (e.errors && e.ground_truth_path_m > 0) {
    std::snprintf(line, sizeof(line), "  path              %.1f m flown in the largest map (ATE %.2f%% of it)\n",
                  e.ground_truth_path_m, 100.0 * e.errors->ate_rmse_m / e.ground_truth_path_m);
    text += line;
  }
  if (e.errors) {
    std::snprintf(line, sizeof(line), "  RPE RMSE          %.4f m, %.3f deg between consecutive posed frames\n",
                  e.errors->rpe_translation_rmse_m, e.errors->rpe_rotation_rmse_deg);
    text += line;
  }
  return text;
}

}  // namespace

std::string Summarize(const Evaluation& e) {
  char line[256];
  std::string text;
  std::snprintf(
      line, sizeof(line), "  frames localized  %d of %d (%.1f%%)%s\n", e.frames_localized, e.frames_total,
      100.0 * e.completeness,
      e.frames_unusable > 0 ? (" - " + std::to_string(e.frames_unusable) + " frames were made unusable").c_str() : "");
  text += line;
  if (e.frames_unreadable > 0) {
    text += "  unreadable        " + std::to_string(e.frames_unreadable) +
            " frames could not be read from the source (see logs/ingest.log)\n";
  }
  if (e.frames_dropped > 0) {
    text +=
        "  dropped           " + std::to_string(e.frames_dropped) + " live frames came while the tracker was busy\n";
  }
  if (e.frames_late_at_source > 0) {
    text += "  late              " + std::to_string(e.frames_late_at_source) +
            " frames left the source more than a frame late: it could not keep the camera's pace, and the run "
            "played slower than the camera (ingest.json)\n";
  }
  std::snprintf(line, sizeof(line), "  keyframes         %d\n  submaps           %d (%d in the largest map%s)\n",
                e.keyframes, e.submaps, e.submaps_merged,
                e.gnss_junctions > 0 ? ("; " + std::to_string(e.gnss_junctions) +
                                        " of its junctions placed by GNSS, where no view joins the submaps")
                                           .c_str()
                                     : "");
  text += line;
  text += ErrorLines(e);
  if (e.submaps_merged > 1) {
    for (const auto& s : e.per_submap) {
      if (s.component != e.largest_component || !s.ate_in_map_m || !s.ate_rmse_m) continue;
      char part[64] = "";
      if (s.ate_in_part_m) std::snprintf(part, sizeof(part), " (%.4f m in its part views join)", *s.ate_in_part_m);
      std::snprintf(line, sizeof(line),
                    "    submap %-6s %4d frames, ATE %.4f m on its own, %.4f m in the merged map%s%s\n",
                    SubmapName(SubmapId(s.submap_id)).c_str(), s.frames, *s.ate_rmse_m, *s.ate_in_map_m, part,
                    s.wrong_merge ? "  WRONG MERGE?" : "");
      text += line;
    }
  }
  if (e.wrong_merges > 0) {
    std::snprintf(line, sizeof(line),
                  "  wrong merges      %d (a submap more than 3x its own ATE in the merged map, and above 0.5%% of "
                  "the %.1f m extent)\n",
                  e.wrong_merges, e.ground_truth_extent_m);
    text += line;
  }
  if (e.tracking_ms_median) {
    std::snprintf(line, sizeof(line), "  tracking time     %.1f ms median, %.1f ms p95\n", *e.tracking_ms_median,
                  *e.tracking_ms_p95);
    text += line;
  }
  return text;
}

std::string SummarizeTrajectory(const Evaluation& e, bool frames_total_known) {
  char line[256];
  if (frames_total_known) {
    std::snprintf(line, sizeof(line), "  frames posed      %d of %d (%.1f%%)\n", e.frames_localized, e.frames_total,
                  100.0 * e.completeness);
  } else {
    std::snprintf(line, sizeof(line), "  frames posed      %d (the sequence's frames not given: --frames-total)\n",
                  e.frames_localized);
  }
  return line + ErrorLines(e);
}

void WriteTrajectoryPlot(const std::string& path, const EvaluationInput& input, const Evaluation& evaluation,
                         const std::string& title) {
  constexpr int kWidth = 1000, kHeight = 800, kMargin = 60, kLegendWidth = 230;
  cv::Mat canvas(kHeight, kWidth, CV_8UC3, cv::Scalar(255, 255, 255));
  // Each map's poses: the largest with the run's alignment, every other merged map and submap
  // aligned on its own (when it can be), so that each is drawn where it belongs.
  std::map<int, std::vector<const PoseRecord*>> by_component;
  int64_t first_ns = INT64_MAX, last_ns = INT64_MIN;
  for (const auto& p : input.poses) {
    by_component[p.component].push_back(&p);
    first_ns = std::min(first_ns, p.t_ns);
    last_ns = std::max(last_ns, p.t_ns);
  }
  const bool aligned = evaluation.errors.has_value();
  std::vector<std::pair<Eigen::Vector3d, const PoseRecord*>> estimate;
  for (const auto& [component, poses] : by_component) {
    std::optional<Sim3d> align;
    if (component == evaluation.largest_component) {
      align = aligned ? evaluation.errors->ground_truth_from_estimate : Sim3d();
    } else if (aligned) {
      std::vector<StampedPose> stamped;
      for (const PoseRecord* p : poses) stamped.push_back({p->t_ns, p->world_from_cam});
      const auto own = CompareTrajectories(stamped, input.ground_truth, input.max_association_gap_ns);
      if (own) align = own->ground_truth_from_estimate;
    }
    if (!align) continue;  // no frame of reference to draw it in
    for (const PoseRecord* p : poses) estimate.push_back({*align * p->world_from_cam.translation, p});
  }
  // The ground truth of the frames the run covers (a run of part of a sequence).
  std::vector<Eigen::Vector3d> truth;
  for (const auto& p : input.ground_truth.poses()) {
    if (input.poses.empty() || (p.t_ns >= first_ns - 500'000'000 && p.t_ns <= last_ns + 500'000'000)) {
      truth.push_back(p.world_from_cam.translation);
    }
  }
  // Seen from above the plane of the motion: the two largest principal axes of the ground truth
  // (else of the estimate), so that a car's drive or a survey is never seen edge-on.
  std::vector<Eigen::Vector3d> cloud = truth;
  if (cloud.size() < 3) {
    for (const auto& [e, p] : estimate) cloud.push_back(e);
  }
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  Eigen::Matrix3d axes = Eigen::Matrix3d::Identity();
  if (cloud.size() >= 3) {
    for (const auto& c : cloud) centre += c;
    centre /= static_cast<double>(cloud.size());
    Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
    for (const auto& c : cloud) covariance += (c - centre) * (c - centre).transpose();
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(covariance);
    if (solver.info() == Eigen::Success) {
      // Eigenvalues ascending: columns 2 and 1 are the largest; the view from their cross product.
      axes.col(0) = solver.eigenvectors().col(2);
      axes.col(1) = solver.eigenvectors().col(1);
      axes.col(2) = axes.col(0).cross(axes.col(1));
    }
  }
  const auto in_plane = [&](const Eigen::Vector3d& p) -> Eigen::Vector2d {
    const Eigen::Vector3d q = axes.transpose() * (p - centre);
    return q.head<2>();
  };
  Eigen::Vector2d lo = Eigen::Vector2d::Constant(1e18), hi = Eigen::Vector2d::Constant(-1e18);
  for (const auto& t : truth) {
    lo = lo.cwiseMin(in_plane(t));
    hi = hi.cwiseMax(in_plane(t));
  }
  for (const auto& [e, p] : estimate) {
    lo = lo.cwiseMin(in_plane(e));
    hi = hi.cwiseMax(in_plane(e));
  }
  if (!(hi.x() >= lo.x())) {
    lo = Eigen::Vector2d(-1, -1);
    hi = Eigen::Vector2d(1, 1);
  }
  const int plot_width = kWidth - kLegendWidth;
  const double span = std::max({hi.x() - lo.x(), hi.y() - lo.y(), 1e-6});
  const double scale = std::min((plot_width - 2.0 * kMargin) / std::max(hi.x() - lo.x(), span * 0.05),
                                (kHeight - 2.0 * kMargin) / std::max(hi.y() - lo.y(), span * 0.05));
  // Centred in the plot's area.
  const double pad_x = std::max(0.0, (plot_width - 2.0 * kMargin - (hi.x() - lo.x()) * scale) / 2);
  const double pad_y = std::max(0.0, (kHeight - 2.0 * kMargin - (hi.y() - lo.y()) * scale) / 2);
  const auto to_px = [&](const Eigen::Vector3d& p) {
    const Eigen::Vector2d q = in_plane(p);
    return cv::Point(static_cast<int>(kMargin + pad_x + (q.x() - lo.x()) * scale),
                     static_cast<int>(kHeight - kMargin - pad_y - (q.y() - lo.y()) * scale));  // second axis up
  };
  for (size_t i = 1; i < truth.size(); ++i) {
    cv::line(canvas, to_px(truth[i - 1]), to_px(truth[i]), cv::Scalar(170, 170, 170), 3, cv::LINE_AA);
  }
  static const cv::Scalar kPalette[] = {{200, 90, 30}, {40, 40, 220}, {40, 160, 40}, {180, 40, 180},  {20, 150, 220},
                                        {140, 140, 0}, {90, 60, 160}, {0, 110, 200}, {100, 100, 100}, {60, 180, 180}};
  // Colours by submap, the largest map's first.
  std::map<int64_t, int> colour_of;
  std::vector<std::pair<int64_t, int>> legend_entries;  // submap, component
  for (int pass = 0; pass < 2; ++pass) {
    for (const auto& [e, p] : estimate) {
      if ((p->component == evaluation.largest_component) != (pass == 0) || colour_of.count(p->submap_id)) continue;
      colour_of[p->submap_id] = static_cast<int>(colour_of.size());
      legend_entries.push_back({p->submap_id, p->component});
    }
  }
  for (size_t i = 0; i < estimate.size(); ++i) {
    const auto& [e, p] = estimate[i];
    const cv::Scalar colour = kPalette[colour_of[p->submap_id] % 10];
    const bool in_largest = p->component == evaluation.largest_component;
    const bool continues = i > 0 && estimate[i - 1].second->submap_id == p->submap_id &&
                           p->frame_index - estimate[i - 1].second->frame_index <= 3;
    if (continues)
      cv::line(canvas, to_px(estimate[i - 1].first), to_px(e), colour, in_largest ? 2 : 1, cv::LINE_AA);
    else
      cv::circle(canvas, to_px(e), 2, colour, cv::FILLED, cv::LINE_AA);
  }
  cv::putText(canvas, title, cv::Point(kMargin, 30), cv::FONT_HERSHEY_SIMPLEX, 0.6, cv::Scalar(0, 0, 0), 1,
              cv::LINE_AA);
  std::string caption = truth.empty()
                            ? "estimate (own frame, no ground truth)"
                            : "grey: ground truth; colours: submaps, Sim3-aligned; top view of the motion's plane";
  if (evaluation.errors) {
    char ate[64];
    std::snprintf(ate, sizeof(ate), "; ATE %.3f m", evaluation.errors->ate_rmse_m);
    caption += ate;
  }
  cv::putText(canvas, caption, cv::Point(kMargin, 52), cv::FONT_HERSHEY_SIMPLEX, 0.45, cv::Scalar(60, 60, 60), 1,
              cv::LINE_AA);
  // Legend: each submap's colour and the map it is in.
  const int legend_x = kWidth - kLegendWidth + 10;
  int legend_y = 90;
  const auto legend_line = [&](const cv::Scalar& colour, int thickness, const std::string& text) {
    if (thickness > 0) {
      cv::line(canvas, cv::Point(legend_x, legend_y - 4), cv::Point(legend_x + 24, legend_y - 4), colour, thickness,
               cv::LINE_AA);
    }
    cv::putText(canvas, text, cv::Point(legend_x + 32, legend_y), cv::FONT_HERSHEY_SIMPLEX, 0.42, cv::Scalar(0, 0, 0),
                1, cv::LINE_AA);
    legend_y += 20;
  };
  if (!truth.empty()) legend_line(cv::Scalar(170, 170, 170), 3, "ground truth");
  constexpr size_t kMaxEntries = 30;
  for (size_t i = 0; i < legend_entries.size() && i < kMaxEntries; ++i) {
    const auto& [submap, component] = legend_entries[i];
    const bool in_largest = component == evaluation.largest_component;
    legend_line(kPalette[colour_of[submap] % 10], in_largest ? 2 : 1,
                "submap " + SubmapName(SubmapId(submap)) + (in_largest ? " (largest map)" : " (apart)"));
  }
  if (legend_entries.size() > kMaxEntries) {
    legend_line(cv::Scalar(), 0, "... and " + std::to_string(legend_entries.size() - kMaxEntries) + " more");
  }
  // Scale bar: a round length near a fifth of the plot's width.
  const double target = (plot_width - 2.0 * kMargin) / scale / 5;
  const double magnitude = std::pow(10.0, std::floor(std::log10(target)));
  const double bar = target >= 5 * magnitude ? 5 * magnitude : target >= 2 * magnitude ? 2 * magnitude : magnitude;
  const int bar_px = static_cast<int>(bar * scale);
  cv::line(canvas, cv::Point(kMargin, kHeight - 25), cv::Point(kMargin + bar_px, kHeight - 25), cv::Scalar(0, 0, 0), 2);
  char bar_text[32];
  std::snprintf(bar_text, sizeof(bar_text), "%g %s", bar, truth.empty() ? "units" : "m");
  cv::putText(canvas, bar_text, cv::Point(kMargin + bar_px + 8, kHeight - 20), cv::FONT_HERSHEY_SIMPLEX, 0.45,
              cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  WritePng(path, canvas);
}

}  // namespace stitch
