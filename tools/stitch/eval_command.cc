// stitch eval: evaluates a run folder, or any TUM trajectory, against ground truth.

#include <cstdio>
#include <filesystem>
#include <fstream>

#include "stitch/eval/evaluation.h"
#include "stitch/io/image_sequence.h"
#include "stitch/util/args.h"
#include "stitch/util/error.h"
#include "tools/stitch/commands.h"
#include "tools/stitch/launch/run_outputs.h"

namespace fs = std::filesystem;

namespace stitch {

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
