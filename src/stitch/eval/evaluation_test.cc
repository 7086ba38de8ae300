#include "stitch/eval/evaluation.h"

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

// A winding ground-truth path with turning cameras, 10 Hz.
Trajectory GroundTruth(int n) {
  std::vector<StampedPose> poses;
  for (int i = 0; i < n; ++i) {
    const double s = 0.1 * i;
    poses.push_back({static_cast<int64_t>(i) * 100'000'000,
                     Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.3 * s, Eigen::Vector3d::UnitZ())),
                             Eigen::Vector3d(5 * std::cos(s), 3 * std::sin(s), 0.5 * s))});
  }
  return Trajectory(poses);
}

// The ground truth seen through est_from_gt (a Sim3), with optional position noise.
std::vector<PoseRecord> Estimate(const Trajectory& gt, const Sim3d& est_from_gt, double noise, int component = 0) {
  Rng rng(4);
  std::vector<PoseRecord> poses;
  int index = 0;
  for (const auto& p : gt.poses()) {
    PoseRecord r;
    r.frame_index = index++;
    r.t_ns = p.t_ns;
    r.submap_id = r.frame_index < 30 ? 1 : 2;
    r.component = component;
    const Eigen::Vector3d centre =
        est_from_gt * p.world_from_cam.translation + noise * Eigen::Vector3d(rng.Normal(), rng.Normal(), rng.Normal());
    r.world_from_cam = Rigid3d(est_from_gt.rotation * p.world_from_cam.rotation, centre);
    poses.push_back(r);
  }
  return poses;
}

const Sim3d kEstFromGt(0.37, Eigen::Quaterniond(Eigen::AngleAxisd(1.2, Eigen::Vector3d(0.2, 1, -0.3).normalized())),
                       Eigen::Vector3d(4, -2, 7));

TEST(Evaluation, Sim3AlignmentRecoversAKnownTransform) {
  const Trajectory gt = GroundTruth(60);
  std::vector<StampedPose> estimated;
  for (const auto& r : Estimate(gt, kEstFromGt, 0.0)) estimated.push_back({r.t_ns, r.world_from_cam});
  const auto errors = CompareTrajectories(estimated, gt);
  ASSERT_TRUE(errors);
  EXPECT_EQ(errors->pairs, 60);
  EXPECT_NEAR(errors->ground_truth_from_estimate.scale, 1 / 0.37, 1e-9);
  EXPECT_NEAR(errors->ground_truth_from_estimate.rotation.angularDistance(kEstFromGt.rotation.conjugate()), 0, 1e-9);
  EXPECT_LT(errors->ate_rmse_m, 1e-9);
  EXPECT_LT(errors->rpe_translation_rmse_m, 1e-9);
  EXPECT_LT(errors->rpe_rotation_rmse_deg, 1e-6);
}

TEST(Evaluation, AteMeasuresNoiseInGroundTruthUnits) {
  const Trajectory gt = GroundTruth(400);
  const double noise_in_gt_m = 0.05;
  std::vector<StampedPose> estimated;
  for (const auto& r : Estimate(gt, kEstFromGt, noise_in_gt_m * kEstFromGt.scale))
    estimated.push_back({r.t_ns, r.world_from_cam});
  const auto errors = CompareTrajectories(estimated, gt);
  ASSERT_TRUE(errors);
  // 3D isotropic noise of sigma per axis has RMS norm sigma * sqrt(3).
  EXPECT_NEAR(errors->ate_rmse_m, noise_in_gt_m * std::sqrt(3.0), 0.01);
}

TEST(Evaluation, CompletenessCountsTheLargestMergedMapOnly) {
  const Trajectory gt = GroundTruth(100);
  std::vector<PoseRecord> poses = Estimate(gt, kEstFromGt, 0.0, 0);
  poses.resize(70);                                      // frames 0..69 in map 0
  for (int i = 60; i < 70; ++i) poses[i].component = 1;  // a smaller, unmerged map
  EvaluationInput input;
  input.frames_total = 100;
  input.poses = poses;
  input.ground_truth = gt;
  input.keyframes = 12;
  input.submaps = 2;
  input.tracking_ms = {1, 2, 3, 4, 100};
  const Evaluation e = Evaluate(input);
  EXPECT_EQ(e.frames_localized, 60);
  EXPECT_DOUBLE_EQ(e.completeness, 0.6);
  EXPECT_EQ(e.largest_component, 0);
  EXPECT_EQ(e.submaps_merged, 2);
  ASSERT_TRUE(e.errors);
  EXPECT_EQ(e.errors->pairs, 60);
  EXPECT_DOUBLE_EQ(*e.tracking_ms_median, 3.0);
  ASSERT_EQ(e.per_submap.size(), 2u);
  ASSERT_TRUE(e.per_submap[0].ate_rmse_m);
  const nlohmann::json j = ToJson(e);
  for (const char* key : {"frames_total", "frames_localized", "completeness", "keyframes", "submaps", "submaps_merged",
                          "ate_rmse_m", "tracking_ms_median"}) {
    EXPECT_TRUE(j.contains(key)) << key;
  }
}

TEST(Evaluation, ThePathFlownIsTheTruePathThroughTheLargestMapsFramesInTimeOrder) {
  // A straight line, 0.5 m a frame; frames 0-29 in the largest map (listed out of order), 30-39 in
  // a smaller one, frame 12 without ground truth (its neighbours' step spans it).
  std::vector<StampedPose> truth;
  for (int i = 0; i < 40; ++i) {
    if (i != 12)
      truth.push_back({static_cast<int64_t>(i) * 100'000'000,
                       Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.5 * i, 0, 0))});
  }
  EvaluationInput input;
  input.frames_total = 40;
  input.ground_truth = Trajectory(truth);
  input.max_association_gap_ns = 10'000'000;
  for (int i = 39; i >= 0; --i) {
    PoseRecord r;
    r.frame_index = i;
    r.t_ns = static_cast<int64_t>(i) * 100'000'000;
    r.submap_id = i < 30 ? 1 : 2;
    r.component = i < 30 ? 0 : 1;
    r.world_from_cam =
        Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.5 * i + (i % 2 ? 0.01 : -0.01), 0.01 * (i % 3), 0));
    input.poses.push_back(r);
  }
  const Evaluation e = Evaluate(input);
  ASSERT_EQ(e.largest_component, 0);
  ASSERT_TRUE(e.errors);
  EXPECT_NEAR(e.ground_truth_path_m, 14.5, 1e-9);  // frames 0 to 29
  const std::string summary = Summarize(e);
  EXPECT_NE(summary.find("14.5 m flown in the largest map"), std::string::npos) << summary;
  EXPECT_NEAR(EvaluationFromJson(ToJson(e)).ground_truth_path_m, 14.5, 1e-9);
}

// Another system's trajectory file (`stitch eval --est`): what it poses, ATE and RPE, and nothing it
// cannot tell (it said "keyframes 0, submaps 1" and 100% of a sequence it did not know).
TEST(Evaluation, ATrajectoryAloneIsSummarizedByWhatItTells) {
  const Trajectory gt = GroundTruth(60);
  EvaluationInput input;
  input.ground_truth = gt;
  input.poses = Estimate(gt, kEstFromGt, 0.01);
  input.frames_total = 60;
  const Evaluation e = Evaluate(input);
  const std::string alone = SummarizeTrajectory(e, false);
  EXPECT_NE(alone.find("frames posed      60 (the sequence's frames not given"), std::string::npos) << alone;
  EXPECT_EQ(alone.find("keyframes"), std::string::npos) << alone;
  EXPECT_EQ(alone.find("submaps"), std::string::npos) << alone;
  EXPECT_NE(alone.find("ATE RMSE"), std::string::npos) << alone;
  EXPECT_NE(alone.find("RPE RMSE"), std::string::npos) << alone;
  const std::string known = SummarizeTrajectory(e, true);
  EXPECT_NE(known.find("frames posed      60 of 60 (100.0%)"), std::string::npos) << known;
}

// The ground truth's 100 frames seen exactly in one map, submap 2 (frames 30..99) shifted as a
// whole by `shift` units along x.
EvaluationInput ShiftedSecondSubmap(double shift) {
  EvaluationInput input;
  input.frames_total = 100;
  input.ground_truth = GroundTruth(100);
  input.poses = Estimate(input.ground_truth, kEstFromGt, 0.0, 0);
  for (auto& p : input.poses) {
    if (p.submap_id == 2) p.world_from_cam.translation += Eigen::Vector3d(shift, 0, 0);
  }
  return input;
}

TEST(Evaluation, AMisplacedSubmapShowsInItsAteInTheMergedMap) {
  // Submap 2 shifted as a whole: alone it is exact, in the map it is not.
  const Evaluation e = Evaluate(ShiftedSecondSubmap(0.3));
  ASSERT_EQ(e.per_submap.size(), 2u);
  for (const SubmapEvaluation& s : e.per_submap) {
    ASSERT_TRUE(s.ate_rmse_m && s.ate_in_map_m);
    EXPECT_LT(*s.ate_rmse_m, 1e-9);
    EXPECT_GT(*s.ate_in_map_m, 0.1);  // 0.3 units = 0.81 m, shared out by the alignment
  }
  EXPECT_NE(Summarize(e).find("in the merged map"), std::string::npos);
  EXPECT_TRUE(ToJson(e)["per_submap"][0].contains("ate_in_map_m"));
  // Each submap is exact alone and far off in the map, more than 0.5% of the extent: both count
  // as wrong merges; and the figures survive report.json.
  EXPECT_GT(e.ground_truth_extent_m, 0);
  EXPECT_EQ(e.wrong_merges, 2);
  EXPECT_NE(Summarize(e).find("wrong merges      2"), std::string::npos) << Summarize(e);
  EXPECT_NE(Summarize(e).find("WRONG MERGE?"), std::string::npos);
  testing::TempDir dir;
  WriteReport(dir / "report.json", e, nlohmann::json{{"source", "test"}});
  const Evaluation back = ReadReport(dir / "report.json");
  EXPECT_EQ(back.wrong_merges, 2);
  EXPECT_EQ(back.frames_localized, e.frames_localized);
  ASSERT_TRUE(back.errors);
  EXPECT_DOUBLE_EQ(back.errors->ate_rmse_m, e.errors->ate_rmse_m);
}

// Joined by a GNSS junction, not by views: the same misplacement is the junction's error, shown
// in the map, but no wrong merge; each part is judged on its own.
TEST(Evaluation, ASubmapJoinedByGnssIsJudgedWithinItsPart) {
  EvaluationInput input = ShiftedSecondSubmap(0.3);
  input.view_part = {{1, 1}, {2, 2}};
  const Evaluation e = Evaluate(input);
  EXPECT_EQ(e.wrong_merges, 0);
  for (const SubmapEvaluation& s : e.per_submap) {
    ASSERT_TRUE(s.ate_in_map_m && s.ate_in_part_m);
    EXPECT_GT(*s.ate_in_map_m, 0.1);
    EXPECT_LT(*s.ate_in_part_m, 1e-6);
  }
  EXPECT_NE(Summarize(e).find("in its part views join"), std::string::npos) << Summarize(e);
  // One part with both submaps: the merge by views is judged as before.
  input.view_part = {{1, 1}, {2, 1}};
  EXPECT_EQ(Evaluate(input).wrong_merges, 2);
}

TEST(Evaluation, ASubmapPlacedWithinHalfAPercentOfTheExtentIsNoWrongMerge) {
  const Evaluation e = Evaluate(ShiftedSecondSubmap(1e-4));
  EXPECT_EQ(e.wrong_merges, 0);
  EXPECT_THROW(EvaluationFromJson(nlohmann::json::object()), Error);
}

TEST(Evaluation, NoGroundTruthGivesNullAte) {
  EvaluationInput input;
  input.frames_total = 10;
  input.poses = Estimate(GroundTruth(10), kEstFromGt, 0.0);
  const Evaluation e = Evaluate(input);
  EXPECT_FALSE(e.errors);
  EXPECT_TRUE(ToJson(e)["ate_rmse_m"].is_null());
  testing::TempDir dir;
  WriteTrajectoryPlot(dir / "plot.png", input, e, "no ground truth");
  EXPECT_TRUE(std::filesystem::exists(dir / "plot.png"));
}

TEST(Evaluation, PoseRecordsRoundTrip) {
  testing::TempDir dir;
  const auto poses = Estimate(GroundTruth(5), kEstFromGt, 0.0);
  WritePoseRecords(dir / "poses.tsv", poses);
  const auto back = ReadPoseRecords(dir / "poses.tsv");
  ASSERT_EQ(back.size(), poses.size());
  EXPECT_EQ(back[3].t_ns, poses[3].t_ns);
  EXPECT_EQ(back[3].submap_id, poses[3].submap_id);
  EXPECT_NEAR((back[3].world_from_cam.translation - poses[3].world_from_cam.translation).norm(), 0, 1e-6);
}

// The pixels of the plot's drawing area (below the title, left of the legend, above the scale
// bar) in `colour` (BGR, within a small tolerance): their bounding box.
cv::Rect PixelsOf(const cv::Mat& image, const cv::Scalar& colour) {
  const cv::Mat area = image(cv::Rect(0, 60, 760, 700));
  cv::Mat mask;
  cv::inRange(area, colour - cv::Scalar::all(12), colour + cv::Scalar::all(12), mask);
  std::vector<cv::Point> points;
  cv::findNonZero(mask, points);
  return points.empty() ? cv::Rect() : cv::boundingRect(points);
}

// A car's drive (camera y down, the motion in x-z) is drawn from above its plane, never edge-on;
// the ground truth beyond the frames played is left out; an unmerged submap is drawn where it
// belongs, with a legend entry of its own.
TEST(Evaluation, ThePlotShowsThePlaneOfTheMotionTheFramesPlayedAndEveryMap) {
  std::vector<StampedPose> truth;
  for (int i = 0; i < 1000; ++i) {  // 1 Hz: 100 m along x, 60 m along z (winding), then 840 m more along x
    const Eigen::Vector3d centre = i < 100   ? Eigen::Vector3d(i, 1.5, 0)
                                   : i < 160 ? Eigen::Vector3d(99 + 3 * std::sin((i - 100) / 5.0), 1.5, i - 99)
                                             : Eigen::Vector3d(99 + (i - 160), 1.5, 60);
    truth.push_back({static_cast<int64_t>(i) * 1'000'000'000, Rigid3d(Eigen::Quaterniond::Identity(), centre)});
  }
  EvaluationInput input;
  input.ground_truth = Trajectory(truth);
  for (int i = 0; i < 160; ++i) {  // frames 0..159 played: 0..119 in the largest map, 125..159 apart
    if (i >= 120 && i < 125) continue;
    PoseRecord r;
    r.frame_index = i;
    r.t_ns = truth[i].t_ns;
    r.submap_id = i < 120 ? 1 : 2;
    r.component = i < 120 ? 0 : 1;
    const Eigen::Vector3d centre =
        i < 120 ? Eigen::Vector3d(0.5 * truth[i].world_from_cam.translation)
                : Eigen::Vector3d(2.0 * truth[i].world_from_cam.translation + Eigen::Vector3d(7, 7, 7));
    r.world_from_cam = Rigid3d(Eigen::Quaterniond::Identity(), centre);
    input.poses.push_back(r);
  }
  input.frames_total = 160;
  const Evaluation evaluation = Evaluate(input);
  ASSERT_EQ(evaluation.largest_component, 0);
  testing::TempDir dir;
  WriteTrajectoryPlot(dir / "plot.png", input, evaluation, "drive");
  const cv::Mat image = cv::imread(dir / "plot.png");
  ASSERT_FALSE(image.empty());
  const cv::Rect largest = PixelsOf(image, cv::Scalar(200, 90, 30));  // the first colour
  const cv::Rect apart = PixelsOf(image, cv::Scalar(40, 40, 220));    // the second
  // Both legs of the largest map spread over the plot (100 m by 20 m, not a line).
  EXPECT_GT(largest.width, 300) << largest;
  EXPECT_GT(largest.height, 60) << largest;
  // The submap apart is drawn along the second leg, aligned on its own (35 m long).
  EXPECT_GT(std::max(apart.width, apart.height), 150) << apart;
  // Clipped: the 840 m the run did not play would shrink the 160 m it did to a fifth of the plot.
  const cv::Rect grey = PixelsOf(image, cv::Scalar(170, 170, 170));
  EXPECT_LT(std::max(grey.width, grey.height), 800) << grey;
  EXPECT_GT(std::max(grey.width, grey.height), 400) << grey;
}

}  // namespace
}  // namespace stitch
