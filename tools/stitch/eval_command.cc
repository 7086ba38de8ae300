// stitch eval: evaluates a run folder, or any TUM trajectory, against ground truth.

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>

#include <nlohmann/json.hpp>

#include "stitch/eval/evaluation.h"
#include "stitch/eval/georeference.h"
#include "stitch/geo/geo_outputs.h"
#include "stitch/geo/geodetic.h"
#include "stitch/io/image_sequence.h"
#include "stitch/util/args.h"
#include "stitch/util/error.h"
#include "stitch/util/text_file.h"
#include "tools/stitch/commands.h"
#include "tools/stitch/launch/run_outputs.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

// Truth samples this far apart are still interpolated between in the absolute mode (a survey
// receiver's 5 Hz track).
constexpr int64_t kAbsoluteMaxGapNs = 250'000'000;

// "LAT,LON,HEIGHT" as a place on Earth; throws stitch::Error saying why not.
GeodeticPoint ParseOrigin(const std::string& text) {
  GeodeticPoint origin;
  char tail = 0;
  if (std::sscanf(text.c_str(), "%lf,%lf,%lf%c", &origin.latitude_deg, &origin.longitude_deg, &origin.height_m,
                  &tail) != 3) {
    throw Error("--origin needs LATITUDE,LONGITUDE,HEIGHT (degrees, degrees, metres above the ellipsoid), not \"" +
                text + "\"");
  }
  if (const std::string why = WhyNotOnEarth(origin); !why.empty()) throw Error("--origin: " + why);
  return origin;
}

// A trajectory in WGS 84 (trajectory_wgs84.csv, every map's positions) in `plane`'s ENU frame.
Trajectory InEnu(const std::vector<GeoTrack>& tracks, const LocalTangentPlane& plane) {
  std::vector<StampedPose> poses;
  for (const GeoTrack& track : tracks) {
    for (const GeoTrack::Point& p : track.points) {
      StampedPose pose;
      pose.t_ns = p.t_ns;
      pose.world_from_cam.translation = plane.ToEnu(p.position);
      poses.push_back(pose);
    }
  }
  return Trajectory(std::move(poses));
}

// --absolute: the estimate against the truth where each says it is, no alignment.
int EvaluateAbsolute(const std::string& estimate_path, const std::string& truth_path, const std::string& kitti_times,
                     const std::string& origin_text, const std::string& out_dir) {
  if (truth_path.empty()) throw Error("--absolute needs --gt");
  const bool estimate_on_earth = IsGeoTrajectoryCsv(estimate_path);
  const bool truth_on_earth = IsGeoTrajectoryCsv(truth_path);
  std::vector<GeoTrack> estimate_tracks, truth_tracks;
  if (estimate_on_earth) estimate_tracks = ReadGeoTrajectoryCsv(estimate_path);
  if (truth_on_earth) truth_tracks = ReadGeoTrajectoryCsv(truth_path);
  std::optional<LocalTangentPlane> plane;
  if (!origin_text.empty()) {
    plane.emplace(ParseOrigin(origin_text));
  } else if (estimate_on_earth != truth_on_earth) {
    throw Error(
        "one trajectory is in WGS 84 and the other in a local frame: give that frame's ENU origin with --origin "
        "LAT,LON,HEIGHT (a synthetic flight's is in its geo/georeference.json)");
  } else if (truth_on_earth) {
    for (const GeoTrack& track : truth_tracks) {
      if (!track.points.empty()) {
        plane.emplace(track.points.front().position);
        break;
      }
    }
    if (!plane) throw Error(truth_path + ": no position");
  }
  const Trajectory estimate = estimate_on_earth ? InEnu(estimate_tracks, *plane) : Trajectory::ReadTum(estimate_path);
  const Trajectory truth = truth_on_earth ? InEnu(truth_tracks, *plane) : ReadGroundTruth(truth_path, kitti_times);
  std::vector<PoseRecord> records;
  for (const StampedPose& pose : estimate.poses()) {
    PoseRecord record;
    record.t_ns = pose.t_ns;
    record.world_from_cam = pose.world_from_cam;
    records.push_back(record);
  }
  std::vector<const PoseRecord*> poses;
  for (const PoseRecord& record : records) poses.push_back(&record);
  const std::optional<AbsoluteErrors> errors = MeasureAbsolute(poses, Sim3d(), truth, kAbsoluteMaxGapNs);
  if (!errors) throw Error(estimate_path + ": no position at a time the truth covers");
  const double rms = std::hypot(errors->horizontal_rms_m, errors->vertical_rms_m);
  std::printf(
      "absolute, no alignment: %d of %zu positions at a time the truth covers\n"
      "horizontal RMS %.4f m, vertical RMS %.4f m, 3D RMS %.4f m; the scale a similarity fit would still change: "
      "%+.3f%%\n",
      errors->frames, estimate.size(), errors->horizontal_rms_m, errors->vertical_rms_m, rms,
      100.0 * errors->scale_error);
  if (plane) {
    std::printf("in the ENU frame at %.9f, %.9f, %.3f m\n", plane->origin().latitude_deg, plane->origin().longitude_deg,
                plane->origin().height_m);
  }
  if (!out_dir.empty()) {
    fs::create_directories(out_dir);
    nlohmann::json report = {{"positions", estimate.size()},
                             {"matched", errors->frames},
                             {"horizontal_rms_m", errors->horizontal_rms_m},
                             {"vertical_rms_m", errors->vertical_rms_m},
                             {"rms_m", rms},
                             {"scale_error", errors->scale_error}};
    if (plane) {
      report["enu_origin"] = {{"latitude_deg", plane->origin().latitude_deg},
                              {"longitude_deg", plane->origin().longitude_deg},
                              {"height_m", plane->origin().height_m}};
    }
    WriteFileAtomically((fs::path(out_dir) / "absolute.json").string(), report.dump(1) + "\n");
    std::printf("wrote %s/absolute.json\n", out_dir.c_str());
  }
  return 0;
}

}  // namespace

int EvalCommand(int argc, char** argv) {
  std::vector<std::string> run_dirs;
  std::string estimate_path, truth_path, out_dir;
  int frames_total = 0;
  ArgParser args("stitch eval",
                 "Evaluates a run: ATE RMSE after Sim3 (Umeyama) alignment, RPE, completeness, keyframes, submaps. "
                 "Give a run folder to rebuild its report.json and trajectory.png, or --est (and --gt) to evaluate any "
                 "TUM-format trajectory, e.g. one from another SLAM system.");
  args.AddPositional(&run_dirs, "RUN_DIR", "a folder written by `stitch run`");
  args.AddOption("--est", &estimate_path, "FILE", "estimated trajectory, TUM format");
  args.AddOption("--gt", &truth_path, "FILE",
                 "ground truth: TUM, KITTI poses (poses/NN.txt) or EuRoC (state_groundtruth_estimate0/data.csv)");
  std::string kitti_times;
  args.AddOption("--gt-times", &kitti_times, "FILE",
                 "with KITTI poses: the sequence's times.txt (default: sequences/NN/times.txt beside poses/)");
  args.AddOption("--frames-total", &frames_total, "N",
                 "frames in the sequence, for completeness (default: poses in --est)");
  args.AddOption("--out", &out_dir, "DIR", "with --est: write report.json and trajectory.png here");
  std::string align_as;
  args.AddOption("--align-as", &align_as, "RUN_DIR",
                 "with --est: align with that run's alignment (its trajectory.tum against its groundtruth.tum) "
                 "instead of the estimate's own: a flight in that run's saved map (stitch run --map), judged where "
                 "that map puts it");
  bool absolute = false;
  args.AddFlag("--absolute", &absolute,
               "with --est and --gt: no alignment at all, each where it says it is: a geo-referenced run's "
               "geo/trajectory_wgs84.csv, or a TUM trajectory in the truth's metric frame; prints the horizontal, "
               "vertical and 3D RMS (--out: absolute.json). Either file may be a trajectory_wgs84.csv: two are "
               "compared in the ENU frame at the truth's first position");
  std::string origin;
  args.AddOption("--origin", &origin, "LAT,LON,HEIGHT",
                 "with --absolute, where one trajectory is in WGS 84 and the other a TUM file in a local ENU frame: "
                 "that frame's origin (degrees, degrees, metres above the ellipsoid)");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    if (!run_dirs.empty()) {
      if (!estimate_path.empty()) throw Error("give either a run folder or --est, not both");
      RunInfo info = LoadRunInfo(run_dirs[0]);
      info.notes.clear();
      const Evaluation evaluation = FinishRunOutputs(run_dirs[0], &info);
      std::printf("%s\n%s", info.source.c_str(), Summarize(evaluation).c_str());
      for (const auto& figures : info.geo_figures) std::printf("%s\n", figures.c_str());
      for (const auto& note : info.notes) std::printf("note: %s\n", note.c_str());
      return 0;
    }
    if (estimate_path.empty()) throw Error("nothing to evaluate: give a run folder or --est FILE (see --help)");
    if (!origin.empty() && !absolute) throw Error("--origin goes with --absolute");
    if (absolute) {
      if (!align_as.empty()) throw Error("--absolute aligns nothing: leave --align-as out");
      return EvaluateAbsolute(estimate_path, truth_path, kitti_times, origin, out_dir);
    }
    if (!align_as.empty()) {
      if (truth_path.empty()) throw Error("--align-as needs --gt");
      const Trajectory theirs = Trajectory::ReadTum((fs::path(align_as) / "trajectory.tum").string());
      const auto aligned =
          CompareTrajectories(theirs.poses(), Trajectory::ReadTum((fs::path(align_as) / "groundtruth.tum").string()));
      if (!aligned) throw Error(align_as + ": its trajectory has no alignment to its ground truth");
      const Trajectory truth = ReadGroundTruth(truth_path, kitti_times);
      const Trajectory ours = Trajectory::ReadTum(estimate_path);
      const auto errors = CompareTrajectories(ours.poses(), truth, 50'000'000, aligned->ground_truth_from_estimate);
      if (!errors) throw Error(estimate_path + ": fewer than 3 poses with ground truth");
      std::printf(
          "aligned as %s (its own ATE %.4f m over %d frames, scale %.4f)\n"
          "ATE RMSE %.4f m over %d frames with that alignment (median %.4f, max %.4f)\n",
          align_as.c_str(), aligned->ate_rmse_m, aligned->pairs, aligned->ground_truth_from_estimate.scale,
          errors->ate_rmse_m, errors->pairs, errors->ate_median_m, errors->ate_max_m);
      return 0;
    }
    EvaluationInput input;
    const Trajectory estimate = Trajectory::ReadTum(estimate_path);
    for (size_t i = 0; i < estimate.size(); ++i) {
      PoseRecord p;
      p.frame_index = static_cast<int>(i);
      p.t_ns = estimate.poses()[i].t_ns;
      p.submap_id = 0;
      p.component = 0;
      p.world_from_cam = estimate.poses()[i].world_from_cam;
      input.poses.push_back(p);
    }
    input.frames_total = frames_total > 0 ? frames_total : static_cast<int>(estimate.size());
    input.submaps = estimate.empty() ? 0 : 1;
    if (!truth_path.empty()) input.ground_truth = ReadGroundTruth(truth_path, kitti_times);
    const Evaluation evaluation = Evaluate(input);
    std::printf("%s", SummarizeTrajectory(evaluation, frames_total > 0).c_str());
    if (!out_dir.empty()) {
      fs::create_directories(out_dir);
      WriteReport((fs::path(out_dir) / "report.json").string(), evaluation);
      WriteTrajectoryPlot((fs::path(out_dir) / "trajectory.png").string(), input, evaluation, estimate_path);
      std::printf("wrote %s/report.json and trajectory.png\n", out_dir.c_str());
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch eval: %s\n", e.what());
    return 1;
  }
}

}  // namespace stitch
