#pragma once
// Evaluation of a run against ground truth (docs/method.md, "Evaluation protocol"):
//  - completeness: frames with a pose in the largest merged map / frames in the sequence;
//  - ATE RMSE after Sim3 (Umeyama) alignment over the frames that have a pose, globally and per
//    submap; RPE between consecutive posed frames after the same alignment;
//  - keyframes and submaps retained, tracking time.

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "stitch/geometry/rigid3.h"
#include "stitch/io/trajectory.h"
#include "stitch/records/pose_record.h"

namespace stitch {

struct EvaluationInput {
  int frames_total = 0;             // frames in the sequence
  int frames_unusable = 0;          // of those, replaced by the failure schedule
  int frames_unreadable = 0;        // of those, the source could not read (an empty frame reached the tracker)
  int frames_dropped = 0;           // of those, live frames the tracker had no time for
  int frames_late_at_source = 0;    // real-time playback: frames the source sent late (source_record.h)
  std::vector<PoseRecord> poses;    // the run's final poses
  Trajectory ground_truth;          // may be empty
  std::vector<double> tracking_ms;  // per processed frame
  int keyframes = 0;
  int submaps = 0;
  int64_t max_association_gap_ns = 50'000'000;  // ground-truth interpolation window
  // Where GNSS junctions join parts of a map that no view joins (edges.tsv): each submap's part,
  // named by one of its submaps. A submap not listed is a part with its whole merged map.
  std::map<int64_t, int64_t> view_part;
};

struct SubmapEvaluation {
  int64_t submap_id = -1;
  int component = -1;
  int frames = 0;
  int frames_with_ground_truth = 0;
  std::optional<double> ate_rmse_m;  // this submap aligned on its own (needs 3 poses)
  // In the largest merged map: this submap's frames under the map's alignment. Far above
  // ate_rmse_m, the merge placed the submap badly.
  std::optional<double> ate_in_map_m;
  // Where GNSS junctions join the largest map's parts: this submap's frames under its part's own
  // alignment (what its merges by views did to it; the junctions' error is ate_in_map_m's rest).
  std::optional<double> ate_in_part_m;
  // A wrong merge: in the largest map, ate_in_part_m (else ate_in_map_m) is more than 3x
  // ate_rmse_m and above 0.5% of the ground truth's extent. A junction by GNSS is not a merge by
  // views: its error is the fixes' (docs/geo.md), not a wrong merge.
  bool wrong_merge = false;
};

struct TrajectoryErrors {
  int pairs = 0;
  Sim3d ground_truth_from_estimate;
  double ate_rmse_m = 0, ate_median_m = 0, ate_max_m = 0;
  double rpe_translation_rmse_m = 0;  // between consecutive posed frames
  double rpe_rotation_rmse_deg = 0;
};

struct Evaluation {
  int frames_total = 0;
  int frames_unusable = 0;
  int frames_unreadable = 0;
  int frames_dropped = 0;
  int frames_late_at_source = 0;
  int frames_localized = 0;  // with a pose in the largest merged map
  double completeness = 0;   // frames_localized / frames_total
  int keyframes = 0;
  int submaps = 0;
  int submaps_merged = 0;  // submaps in the largest merged map
  int gnss_junctions = 0;  // of its junctions, those GNSS placed (no view joins their submaps; edges.tsv)
  int largest_component = -1;
  std::optional<TrajectoryErrors> errors;  // largest map vs ground truth
  double ground_truth_extent_m = 0;        // diagonal of the box around the posed frames' true positions
  double ground_truth_path_m = 0;          // length of the true path through the largest map's frames, in time order
  int wrong_merges = 0;                    // submaps of the largest map with wrong_merge
  std::vector<SubmapEvaluation> per_submap;
  std::optional<double> tracking_ms_median, tracking_ms_p95;
  bool has_ground_truth = false;
};

// Aligns `estimated` to `ground_truth` with a Sim3 (Umeyama), or with `alignment` where given
// (another run's, for a trajectory in that run's map), and measures the errors. Empty when fewer
// than 3 poses have ground truth or they are degenerate (collinear).
std::optional<TrajectoryErrors> CompareTrajectories(const std::vector<StampedPose>& estimated,
                                                    const Trajectory& ground_truth,
                                                    int64_t max_association_gap_ns = 50'000'000,
                                                    const std::optional<Sim3d>& alignment = std::nullopt);

Evaluation Evaluate(const EvaluationInput& input);
// report.json's figures (ToJson) and back (EvaluationFromJson, which throws stitch::Error naming
// a missing key); ReadReport reads a run folder's report.json.
nlohmann::json ToJson(const Evaluation& evaluation);
Evaluation EvaluationFromJson(const nlohmann::json& json);
Evaluation ReadReport(const std::string& path);
// Writes report.json (ToJson, with `run` under "run" when given) atomically: the one writer.
// `run` (run.json's content), `merges` (the merger's edges and their verdicts) and `georeference`
// (RunGeoReference::ToJson) go in as they are.
void WriteReport(const std::string& path, const Evaluation& evaluation, const nlohmann::json& run = nullptr,
                 const nlohmann::json& merges = nullptr, const nlohmann::json& georeference = nullptr);
// A few lines for the terminal.
std::string Summarize(const Evaluation& evaluation);
// The same for a trajectory alone (another system's, `stitch eval --est`): the frames it poses
// (completeness only when the sequence's frame count is known), ATE, path and RPE; no keyframes
// or submaps, which a trajectory file does not tell.
std::string SummarizeTrajectory(const Evaluation& evaluation, bool frames_total_known);

// Top view of the plane of the motion (the two largest principal axes of the ground truth, else
// of the estimate): the ground truth of the frames the run covers (grey) and every map aligned
// to it, one colour per submap with a legend; the largest map with the run's alignment, every
// other merged map or submap aligned on its own (left out when it cannot be). Without ground
// truth, the largest map alone in its own frame.
void WriteTrajectoryPlot(const std::string& path, const EvaluationInput& input, const Evaluation& evaluation,
                         const std::string& title);

}  // namespace stitch
