// The SLAM core (tracker and mapper algorithms, no transport) on synthetic flights with exact
// ground truth.

#include "stitch/pipeline/inline_pipeline.h"

#include <cstdio>
#include <set>

#include <gtest/gtest.h>

#include "stitch/source/source.h"
#include "stitch/testing/default_vocabulary.h"

namespace stitch {
namespace {

using testing::DefaultVocabulary;

SyntheticOptions StripFlight(int frames) {
  SyntheticOptions synthetic;
  synthetic.flight.num_frames = frames;
  synthetic.flight.num_strips = 1;
  synthetic.flight.strip_length_m = 1.15 * frames;  // the default flight's speed
  return synthetic;
}

double Extent(const Trajectory& truth) {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e18), hi = -lo;
  for (const auto& p : truth.poses()) {
    lo = lo.cwiseMin(p.world_from_cam.translation);
    hi = hi.cwiseMax(p.world_from_cam.translation);
  }
  return (hi - lo).maxCoeff();
}

TEST(InlinePipeline, CalmFlightIsTrackedCompletelyAndAccurately) {
  const SyntheticOptions synthetic = StripFlight(200);
  SourceSpec spec;
  spec.synthetic = synthetic;
  spec.failures = "none";
  FailureSchedule unused;
  auto sequence = OpenSource(spec, &unused);
  const InlineRun run = RunInline(*sequence, PipelineOptions(), DefaultVocabulary());
  EvaluationInput input;
  input.frames_total = 200;
  input.poses = run.poses;
  input.ground_truth = sequence->ground_truth();
  const Evaluation e = Evaluate(input);
  EXPECT_GE(e.completeness, 0.98);
  EXPECT_EQ(run.submaps, 1);
  ASSERT_TRUE(e.errors);
  const double extent = Extent(sequence->ground_truth());
  EXPECT_LT(e.errors->ate_rmse_m, 0.01 * extent) << "extent " << extent << " m";
  EXPECT_GT(run.keyframes, 10);
}

TEST(InlinePipeline, ObliqueAndForwardCamerasKeepTheirScale) {
  // A camera tilted forward over nearly flat ground: two views have a twin reconstruction (the
  // camera moving into a tilted ground) that tracks as well as the true one for a while, and
  // then lets the map's scale collapse frame by frame (tens of metres off on 150 m).
  struct Camera {
    double pitch_deg, altitude_m, visibility_m;
  };
  for (const Camera& camera : {Camera{45, 40, 600}, Camera{80, 15, 300}}) {
    SyntheticOptions synthetic = StripFlight(150);
    synthetic.flight.camera_pitch_deg = camera.pitch_deg;
    synthetic.flight.altitude_m = camera.altitude_m;
    synthetic.world.visibility_m = camera.visibility_m;
    SourceSpec spec;
    spec.synthetic = synthetic;
    spec.failures = "none";
    FailureSchedule unused;
    auto sequence = OpenSource(spec, &unused);
    const InlineRun run = RunInline(*sequence, PipelineOptions(), DefaultVocabulary());
    EvaluationInput input;
    input.frames_total = 150;
    input.poses = run.poses;
    input.ground_truth = sequence->ground_truth();
    const Evaluation e = Evaluate(input);
    SCOPED_TRACE("camera pitched " + std::to_string(camera.pitch_deg) + " degrees");
    EXPECT_GE(e.completeness, 0.8);  // a few frames before the two views can tell
    EXPECT_EQ(run.submaps, 1);
    ASSERT_TRUE(e.errors);
    const double extent = Extent(sequence->ground_truth());
    EXPECT_LT(e.errors->ate_rmse_m, 0.005 * extent) << "extent " << extent << " m";
  }
}

TEST(InlinePipeline, AGustClosesTheSubmapAndANewOneStartsAtOnce) {
  const SyntheticOptions synthetic = StripFlight(200);
  SourceSpec spec;
  spec.synthetic = synthetic;
  spec.failures = "90:10";
  FailureSchedule unused;
  auto sequence = OpenSource(spec, &unused);
  const InlineRun run = RunInline(*sequence, PipelineOptions(), DefaultVocabulary());
  EXPECT_GE(run.submaps, 2);
  // Every usable frame (not in the gust) but a few around the gust and the first two has a pose.
  int usable = 0, posed = 0;
  std::set<int> with_pose;
  for (const auto& p : run.poses) with_pose.insert(p.frame_index);
  for (int i = 0; i < 200; ++i) {
    if (i >= 90 && i < 100) continue;
    ++usable;
    posed += with_pose.count(i) > 0;
  }
  EXPECT_GE(posed, usable - 20) << posed << " of " << usable << " usable frames posed";
  // The frame right after losing track is reported as lost, with a reason.
  bool lost_reported = false;
  for (const auto& f : run.frames) lost_reported |= f.result.state == TrackingState::kLost && !f.result.detail.empty();
  EXPECT_TRUE(lost_reported);
  // The merger joins the two submaps into one map, as accurate as each submap alone.
  EvaluationInput input;
  input.frames_total = 200;
  input.poses = run.merged_poses;
  input.ground_truth = sequence->ground_truth();
  const Evaluation merged = Evaluate(input);
  std::printf("merged: %d submaps in the largest map, %d frames, ATE %.3f m; %zu connections, %zu edges\n",
              merged.submaps_merged, merged.frames_localized, merged.errors ? merged.errors->ate_rmse_m : -1.0,
              0 * run.graph.edges.size() + run.graph.tree.size(), run.graph.edges.size());
  for (const auto& e : run.graph.edges) {
    std::printf("edge %d-%d F=%d M=%d theta=%.1f C=%.1f\n", SubmapNumber(e.a), SubmapNumber(e.b), e.connected_frames,
                e.map_points, e.median_angle_deg, e.strength);
  }
  EXPECT_EQ(merged.submaps_merged, run.submaps);
  EXPECT_GE(merged.frames_localized, posed);
  ASSERT_TRUE(merged.errors);
  EXPECT_LT(merged.errors->ate_rmse_m, 0.01 * Extent(sequence->ground_truth()));
}

}  // namespace
}  // namespace stitch
