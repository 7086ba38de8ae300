// Tracking loss and relocalization (docs/tracking-loss.md) on scripted sequences: frames of the
// synthetic flight played in a chosen order, with blackouts, repeats and blur, so the answer is
// known.

#include <cstdio>
#include <map>
#include <memory>
#include <set>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "stitch/pipeline/inline_pipeline.h"
#include "stitch/source/source.h"
#include "stitch/synthetic/renderer.h"
#include "stitch/synthetic/synthetic_sequence.h"
#include "stitch/testing/default_vocabulary.h"

namespace stitch {
namespace {

// One strip of the default flight, rendered once for all tests.
struct RenderedStrip {
  Camera camera;
  std::vector<cv::Mat> images;
  std::vector<Rigid3d> world_from_cam;
};

const RenderedStrip& Strip() {
  static const RenderedStrip* strip = [] {
    auto* s = new RenderedStrip;
    SourceSpec spec;
    spec.synthetic.flight.num_frames = 120;
    spec.synthetic.flight.num_strips = 1;
    spec.synthetic.flight.strip_length_m = 1.15 * 120;
    spec.failures = "none";
    FailureSchedule unused;
    auto sequence = OpenSource(spec, &unused);
    s->camera = sequence->camera();
    SequenceFrame frame;
    while (sequence->Next(&frame)) {
      s->images.push_back(frame.image.clone());
      s->world_from_cam.push_back(*sequence->ground_truth().PoseAt(frame.t_ns));
    }
    return s;
  }();
  return *strip;
}

using testing::DefaultVocabulary;

// Frames of the strip in a scripted order; -1 is a black frame, -2 - i is frame i blurred
// beyond use. Timestamps are 50 ms apart; ground truth follows the strip's frames.
class ScriptedSequence : public ImageSequence {
 public:
  static constexpr int kBlack = -1;
  static int Blurred(int frame) { return -2 - frame; }

  explicit ScriptedSequence(std::vector<int> script) : script_(std::move(script)) {
    for (size_t i = 0; i < script_.size(); ++i) {
      const int source = script_[i] >= 0 ? script_[i] : script_[i] <= -2 ? -2 - script_[i] : -1;
      if (source >= 0) truth_.Add({Time(static_cast<int>(i)), Strip().world_from_cam[source]});
    }
  }
  std::string description() const override { return "scripted strip"; }
  int size() const override { return static_cast<int>(script_.size()); }
  const Camera& camera() const override { return Strip().camera; }
  double nominal_fps() const override { return 20; }
  const Trajectory& ground_truth() const override { return truth_; }
  bool Next(SequenceFrame* frame) override {
    if (next_ >= script_.size()) return false;
    const int entry = script_[next_];
    frame->index = static_cast<int>(next_);
    frame->t_ns = Time(frame->index);
    if (entry >= 0) {
      frame->image = Strip().images[entry].clone();
    } else if (entry == kBlack) {
      frame->image = cv::Mat::zeros(Strip().images[0].size(), CV_8UC1);
    } else {
      cv::GaussianBlur(Strip().images[-2 - entry], frame->image, cv::Size(0, 0), 12);
    }
    ++next_;
    return true;
  }

 private:
  static int64_t Time(int index) { return 1'000'000'000LL + 50'000'000LL * index; }
  std::vector<int> script_;
  Trajectory truth_;
  size_t next_ = 0;
};

// Appends frames [first, last] of the strip, or `count` copies of an entry.
void Play(std::vector<int>* script, int first, int last) {
  for (int i = first; i <= last; ++i) script->push_back(i);
}
void Repeat(std::vector<int>* script, int entry, int count) {
  script->insert(script->end(), count, entry);
}

InlineRun RunScript(const std::vector<int>& script, const std::string& on_loss, bool keyframe_worker = true) {
  PipelineOptions options;
  options.on_loss = on_loss;
  options.tracking.keyframe_worker = keyframe_worker;
  ScriptedSequence sequence(script);
  return RunInline(sequence, options, DefaultVocabulary());
}

// The strip up to frame 79, then 8 black frames (tracking is lost at frame 82).
std::vector<int> StripThenBlackout() {
  std::vector<int> script;
  Play(&script, 0, 79);
  Repeat(&script, ScriptedSequence::kBlack, 8);
  return script;
}

// The submap policy with these tracking settings.
InlineRun RunScript(const std::vector<int>& script, const TrackingOptions& tracking) {
  PipelineOptions options;
  options.on_loss = "submap";
  options.tracking = tracking;
  ScriptedSequence sequence(script);
  return RunInline(sequence, options, DefaultVocabulary());
}

// The poses of a run of `script` against its ground truth.
Evaluation EvaluateScript(const std::vector<int>& script, const std::vector<PoseRecord>& poses) {
  EvaluationInput input;
  input.frames_total = static_cast<int>(script.size());
  input.poses = poses;
  ScriptedSequence truth(script);
  input.ground_truth = truth.ground_truth();
  return Evaluate(input);
}

const InlineFrame* FirstOkFrom(const InlineRun& run, int from) {
  for (const auto& f : run.frames) {
    if (f.frame_index >= from && f.result.state == TrackingState::kOk) return &f;
  }
  return nullptr;
}

TEST(TrackingLoss, TheBaselineRelocalizesWhenTheCameraReturnsAfterABlackout) {
  std::vector<int> script;
  Play(&script, 0, 79);
  Repeat(&script, ScriptedSequence::kBlack, 8);
  Play(&script, 40, 79);  // back over the mapped half of the strip
  const InlineRun run = RunScript(script, "relocalize");
  EXPECT_EQ(run.submaps, 1);
  // Lost during the blackout, with the reason; the map is kept.
  for (int i = 80 + 3; i < 88; ++i) {
    EXPECT_EQ(run.frames[i].result.state, TrackingState::kLost) << i;
    EXPECT_EQ(run.frames[i].result.reason, TrackingReason::kNotRelocalized) << i;
  }
  // Relocalized within a few frames of the camera's return...
  const InlineFrame* back = FirstOkFrom(run, 88);
  ASSERT_NE(back, nullptr);
  EXPECT_LE(back->frame_index, 88 + 3);
  EXPECT_TRUE(back->result.relocalized);
  // ...at the pose it had over the same place the first time (within 2% of the distance flown
  // between frames 40 and 79, about 45 m).
  std::map<int, Eigen::Vector3d> centre;
  for (const auto& p : run.poses) centre[p.frame_index] = p.world_from_cam.translation;
  ASSERT_TRUE(centre.count(40) && centre.count(79));
  const double span = (centre[79] - centre[40]).norm();
  int compared = 0;
  for (int k = 0; k < 40; ++k) {
    const int replay = 88 + k;
    if (!centre.count(replay) || !centre.count(40 + k)) continue;
    EXPECT_LT((centre[replay] - centre[40 + k]).norm(), 0.02 * span) << "frame " << replay;
    ++compared;
  }
  EXPECT_GE(compared, 36);
  // And against the ground truth (Sim3-aligned, in metres; the strip is 138 m long).
  const Evaluation e = EvaluateScript(script, run.poses);
  ASSERT_TRUE(e.errors);
  EXPECT_LT(e.errors->ate_rmse_m, 0.3);
  EXPECT_LT(e.errors->ate_max_m, 0.8);
  std::printf("relocalized run: ATE %.3f m (max %.3f m) over %d frames\n", e.errors->ate_rmse_m, e.errors->ate_max_m,
              e.frames_localized);
}

TEST(KeyframeWorker, GivesTheSameRunAsTheFrameLoopComputingTheBagOfWordsItself) {
  // A blackout and a return over mapped ground: relocalization queries the database the worker
  // fills, so the runs agree only if every keyframe got there in time.
  std::vector<int> script;
  Play(&script, 0, 79);
  Repeat(&script, ScriptedSequence::kBlack, 8);
  Play(&script, 40, 79);
  const InlineRun in_loop = RunScript(script, "relocalize", false);
  const InlineRun worker = RunScript(script, "relocalize", true);
  ASSERT_EQ(in_loop.frames.size(), worker.frames.size());
  int relocalized = 0;
  for (size_t i = 0; i < worker.frames.size(); ++i) {
    EXPECT_EQ(worker.frames[i].result.state, in_loop.frames[i].result.state) << "frame " << i;
    EXPECT_EQ(worker.frames[i].result.num_tracked_points, in_loop.frames[i].result.num_tracked_points) << "frame " << i;
    relocalized += worker.frames[i].result.relocalized;
  }
  EXPECT_EQ(relocalized, 1);
  ASSERT_EQ(worker.poses.size(), in_loop.poses.size());
  for (size_t i = 0; i < worker.poses.size(); ++i) {
    EXPECT_LT((worker.poses[i].world_from_cam.translation - in_loop.poses[i].world_from_cam.translation).norm(), 1e-9);
  }
}

TEST(TrackingLoss, BackWhereItWasLostTheCameraGoesOnInItsSubmapAtOnce) {
  // A blackout while hovering: the camera is back in the local map it was lost from, with no
  // parallax to the keyframe it relocalizes at, so the submap resumes at the first frame (as the
  // relocalize baseline would) rather than after relocalize_closed_after_frames.
  std::vector<int> script = StripThenBlackout();
  Repeat(&script, 78, 30);
  const InlineRun run = RunScript(script, "submap");
  const SubmapId first = run.frames[10].result.submap;
  EXPECT_EQ(run.frames[82].result.state, TrackingState::kLost);
  const InlineFrame* back = FirstOkFrom(run, 88);
  ASSERT_NE(back, nullptr);
  EXPECT_EQ(back->frame_index, 88) << "resumed at the first frame after the blackout";
  EXPECT_TRUE(back->result.relocalized);
  EXPECT_EQ(back->result.submap, first);
  for (int i = 88; i < static_cast<int>(script.size()); ++i) {
    EXPECT_EQ(run.frames[i].result.state, TrackingState::kOk) << i;
    EXPECT_EQ(run.frames[i].result.submap, first) << i;
  }
  EXPECT_EQ(run.submaps, 1);
  // With resuming off, the new map tries to initialize first (and cannot: no parallax).
  TrackingOptions no_resume;
  no_resume.resume_where_lost = false;
  const InlineRun waited = RunScript(script, no_resume);
  const InlineFrame* later = FirstOkFrom(waited, 88);
  ASSERT_NE(later, nullptr);
  EXPECT_GE(later->frame_index, 83 + 20) << "lost at frame 82; relocalize_closed_after_frames (20) later";
}

TEST(TrackingLoss, AFrameTheMotionModelCannotPlaceIsRelocalizedInItsSubmapBeforeItCountsAsUntracked) {
  // The camera jumps back 95 frames (109 m, beyond the view of the last frame and its reference
  // keyframe) to ground its submap mapped. The motion model's chance matches on the first frame
  // there diverge: it is relocalized in the whole submap (relocalize_untracked), and so are the
  // frames after it: no loss, no new submap.
  std::vector<int> script;
  Play(&script, 0, 100);
  Play(&script, 5, 25);
  TrackingOptions relocalizing;
  relocalizing.relocalize_untracked = true;
  const InlineRun run = RunScript(script, relocalizing);
  const SubmapId first = run.frames[10].result.submap;
  ASSERT_EQ(run.frames[101].result.state, TrackingState::kOk) << run.frames[101].result.detail;
  EXPECT_TRUE(run.frames[101].result.relocalized);
  EXPECT_EQ(run.frames[101].result.submap, first);
  for (size_t i = 101; i < script.size(); ++i) {
    EXPECT_EQ(run.frames[i].result.state, TrackingState::kOk) << i;
    EXPECT_EQ(run.frames[i].result.submap, first) << i;
  }
  EXPECT_EQ(run.submaps, 1);
  const Evaluation evaluation = EvaluateScript(script, run.poses);
  ASSERT_TRUE(evaluation.errors);
  EXPECT_LT(evaluation.errors->ate_max_m, 0.8) << "the relocalized frames are where the camera was";
  // Without it the jump loses the camera, and the submap is closed for a new one.
  TrackingOptions not_relocalizing;
  not_relocalizing.relocalize_untracked = false;
  const InlineRun lost = RunScript(script, not_relocalizing);
  EXPECT_EQ(lost.frames[103].result.state, TrackingState::kLost) << lost.frames[103].result.detail;
  EXPECT_EQ(lost.submaps, 2);
}

TEST(TrackingLoss, ACameraThatMovedOnSinceItWasLostStartsANewSubmap) {
  // The blackout lasts while the aircraft flies on about 12 m (10 frames) at some 70 m: the
  // first frame after it still relocalizes in the local map it was lost from, but sees those
  // points from about 10 degrees away. A new map maps the new ground better (the merger places
  // it), so a new submap starts; allowed any parallax, the same frames resume the old submap.
  std::vector<int> script = StripThenBlackout();
  Play(&script, 90, 119);
  const InlineRun run = RunScript(script, "submap");
  const SubmapId first = run.frames[10].result.submap;
  const InlineFrame* fresh = FirstOkFrom(run, 88);
  ASSERT_NE(fresh, nullptr);
  EXPECT_NE(fresh->result.submap, first) << fresh->result.detail;
  EXPECT_FALSE(fresh->result.relocalized);
  EXPECT_EQ(run.submaps, 2);
  TrackingOptions any;
  any.resume_max_parallax_deg = 90;
  const InlineRun any_parallax = RunScript(script, any);
  const InlineFrame* resumed = FirstOkFrom(any_parallax, 88);
  ASSERT_NE(resumed, nullptr);
  EXPECT_TRUE(resumed->result.relocalized) << resumed->result.detail;
  EXPECT_EQ(resumed->result.submap, first);
  EXPECT_LT(resumed->frame_index, fresh->frame_index) << "relocalized before the new map initialized";
}

TEST(TrackingLoss, ANewMapThatCannotInitializeGivesWayToAClosedSubmapTheCameraIsBackIn) {
  // Resuming where it was lost off: this is the way back for a camera that cannot initialize.
  std::vector<int> script;
  Play(&script, 0, 79);
  Repeat(&script, ScriptedSequence::kBlack, 8);
  Repeat(&script, 60, 40);  // hovering over a mapped place: no parallax to initialize from
  TrackingOptions no_resume;
  no_resume.resume_where_lost = false;
  const InlineRun run = RunScript(script, no_resume);
  const SubmapId first = run.frames[10].result.submap;
  const InlineFrame* back = FirstOkFrom(run, 88);
  ASSERT_NE(back, nullptr);
  EXPECT_TRUE(back->result.relocalized);
  EXPECT_EQ(back->result.submap, first) << "continued in the closed submap";
  // Lost at frame 82 (the third black frame); relocalization into closed submaps is tried once
  // the new map has tried to initialize for relocalize_closed_after_frames (20) frames.
  EXPECT_EQ(run.frames[82].result.state, TrackingState::kLost);
  EXPECT_GE(back->frame_index, 83 + 20);
  EXPECT_LE(back->frame_index, 83 + 20 + 3);
  for (int i = back->frame_index; i < static_cast<int>(script.size()); ++i) {
    EXPECT_EQ(run.frames[i].result.state, TrackingState::kOk) << i;
    EXPECT_EQ(run.frames[i].result.submap, first) << i;
  }
  EXPECT_EQ(run.submaps, 1);
}

TEST(TrackingLoss, AYoungSubmapGivesWayToTheClosedSubmapTheCameraIsBackIn) {
  // The camera returns over mapped ground after a blackout, with parallax enough to start a new
  // submap at once: within return_to_closed_frames it relocalizes into the closed submap, and goes
  // on there as the relocalize baseline would; the young submap closes with what it has. (Not into
  // another young submap: only into one with more keyframes than the young one.)
  std::vector<int> script;
  Play(&script, 0, 79);
  Repeat(&script, ScriptedSequence::kBlack, 8);
  Play(&script, 40, 79);
  TrackingOptions tracking;
  tracking.return_to_closed_frames = 60;
  tracking.resume_where_lost = false;  // it would land in the closed submap before a new one starts
  const InlineRun run = RunScript(script, tracking);
  const SubmapId first = run.frames[10].result.submap;
  const InlineFrame* young = FirstOkFrom(run, 88);
  ASSERT_NE(young, nullptr);
  EXPECT_NE(young->result.submap, first) << "a new submap starts at once";
  const InlineFrame* back = nullptr;
  for (const auto& f : run.frames) {
    if (f.frame_index > young->frame_index && f.result.relocalized && f.result.submap == first) {
      back = &f;
      break;
    }
  }
  ASSERT_NE(back, nullptr) << "never went back into the closed submap";
  EXPECT_LE(back->frame_index, young->frame_index + 60);
  EXPECT_NE(back->result.detail.find("back in closed submap"), std::string::npos) << back->result.detail;
  for (int i = back->frame_index; i < static_cast<int>(script.size()); ++i) {
    EXPECT_EQ(run.frames[i].result.state, TrackingState::kOk) << i;
    EXPECT_EQ(run.frames[i].result.submap, first) << i;
  }
  EXPECT_EQ(run.submaps, 2);
  // Never: without the window (the default) the young submap keeps the camera.
  tracking.return_to_closed_frames = 0;
  const InlineRun kept = RunScript(script, tracking);
  for (int i = young->frame_index; i < static_cast<int>(script.size()); ++i) {
    EXPECT_NE(kept.frames[i].result.submap, first) << i;
  }
}

// Back in a closed submap after a young one, the tracker's new keyframes there have lower ids
// than the young submap's the mapper answered before. They count as in flight until the mapper
// answers them (the tracker counted keyframes above the newest answered id: none, so a lockstep
// tracker did not wait for them and a live one was not held back by them).
TEST(TrackingLoss, KeyframesOfAReopenedSubmapAreInFlightUntilAnswered) {
  std::vector<int> script;
  Play(&script, 0, 79);
  Repeat(&script, ScriptedSequence::kBlack, 8);
  Play(&script, 40, 119);  // back over mapped ground, then on over new ground
  PipelineOptions options;
  options.tracking.return_to_closed_frames = 60;
  options.tracking.resume_where_lost = false;
  ScriptedSequence sequence(script);
  Tracking tracking(options.tracking, sequence.camera(), &DefaultVocabulary(), sequence.nominal_fps());
  LocalMapping mapping(options.mapping, sequence.camera(), options.tracking.orb, &DefaultVocabulary());
  SubmapId first;
  bool young_answered = false;
  int reopened_keyframes = 0;
  SequenceFrame frame;
  while (sequence.Next(&frame)) {
    Tracking::Output output = tracking.Track(frame.image, frame.index, frame.t_ns);
    if (output.closed_submap && mapping.map() && mapping.map()->id() == *output.closed_submap) mapping.CloseSubmap();
    for (size_t k = 0; k < output.new_keyframes.size(); ++k) {
      const KeyframeId id = output.new_keyframes[k].id;
      if (!first.valid()) first = SubmapOf(id);
      if (young_answered && SubmapOf(id) == first) {
        ++reopened_keyframes;
        EXPECT_GE(tracking.KeyframesInFlight(), 1) << "keyframe " << IndexOf(id) << " of the reopened submap";
      }
      MappedKeyframe mapped =
          mapping.MapKeyframe(output.new_keyframes[k], k == 0 ? output.new_points : std::vector<MapPoint>());
      tracking.ApplyUpdate(mapped.for_tracker);
      young_answered |= SubmapOf(id) != first;
      EXPECT_EQ(tracking.KeyframesInFlight(), static_cast<int>(output.new_keyframes.size() - k - 1));
    }
  }
  EXPECT_TRUE(young_answered) << "a young submap started after the blackout";
  EXPECT_GT(reopened_keyframes, 2) << "keyframes made over new ground back in the first submap";
}

TEST(TrackingLoss, FramesMissedBeforeTheCameraIsPlacedAgainArePlacedBackwardFromIt) {
  // After a blackout the camera comes back from ground the map never saw (strip frames 110 down
  // to 40): the first frames over mapped ground see too little of it to relocalize, the first
  // that does is placed, and the frames missed just before it are placed backward from it.
  std::vector<int> script = StripThenBlackout();
  for (int i = 110; i >= 40; --i) script.push_back(i);
  const auto run_with = [&](int retrack) {
    PipelineOptions options;
    options.on_loss = "relocalize";
    options.tracking.retrack_missed_frames = retrack;
    ScriptedSequence sequence(script);
    return RunInline(sequence, options, DefaultVocabulary());
  };
  const InlineRun run = run_with(20);
  const InlineFrame* back = FirstOkFrom(run, 88);
  ASSERT_NE(back, nullptr);
  ASSERT_TRUE(back->result.relocalized);
  std::set<int> placed;
  for (const PoseRecord& pose : run.poses) placed.insert(pose.frame_index);
  // The missed frames placed: a run right before the relocalized frame, each lost at first.
  int backward = 0;
  for (int i = back->frame_index - 1; i >= 88 && placed.count(i); --i) {
    EXPECT_EQ(run.frames[i].result.state, TrackingState::kLost) << i;
    ++backward;
  }
  EXPECT_GE(backward, 2);
  for (int i = 88; i < back->frame_index - backward; ++i) EXPECT_FALSE(placed.count(i)) << i;
  // Off, they stay missed.
  const InlineRun without = run_with(0);
  std::set<int> placed_without;
  for (const PoseRecord& pose : without.poses) placed_without.insert(pose.frame_index);
  EXPECT_EQ(placed_without.size() + backward, placed.size());
  // Where the camera was (the strip is 138 m long): no farther off than the frames placed
  // forward at the edge of the map (about a metre at 70 m).
  const Evaluation e = EvaluateScript(script, run.poses), e_without = EvaluateScript(script, without.poses);
  ASSERT_TRUE(e.errors && e_without.errors);
  EXPECT_LT(e.errors->ate_rmse_m, 0.3);
  EXPECT_LE(e.errors->ate_max_m, 1.05 * e_without.errors->ate_max_m);
  std::printf(
      "relocalized at frame %d, %d missed frames placed backward: ATE %.3f m (max %.3f m); without: %.3f m "
      "(max %.3f m)\n",
      back->frame_index, backward, e.errors->ate_rmse_m, e.errors->ate_max_m, e_without.errors->ate_rmse_m,
      e_without.errors->ate_max_m);
}

TEST(TrackingLoss, ABlackoutDuringInitializationOnlyDelaysIt) {
  std::vector<int> script;
  Play(&script, 0, 0);  // the reference frame of the first initialization attempt
  Repeat(&script, ScriptedSequence::kBlack, 5);
  Play(&script, 6, 59);
  const InlineRun run = RunScript(script, "submap");
  for (int i = 1; i <= 5; ++i) {
    EXPECT_EQ(run.frames[i].result.state, TrackingState::kInitializing) << i;
    EXPECT_EQ(run.frames[i].result.reason, TrackingReason::kTooFewFeatures) << i;
  }
  const InlineFrame* first = FirstOkFrom(run, 0);
  ASSERT_NE(first, nullptr);
  EXPECT_LE(first->frame_index, 12);
  EXPECT_EQ(run.submaps, 1);
  EXPECT_GE(static_cast<int>(run.poses.size()), 60 - 12);
}

// A camera that hovers before it moves: the new map initializes only once the camera moved, and
// then places the frames it waited through (its reference, keyframe 0, and the hovering frames
// that matched it) where they were: at the reference, not spread along the motion.
TEST(Initialization, TheFramesANewMapWaitedThroughArePlacedInItWhereTheCameraWas) {
  std::vector<int> script;
  Repeat(&script, 0, 5);  // hovering over the strip's first frame
  Play(&script, 1, 40);
  const InlineRun run = RunScript(script, "submap");
  const InlineFrame* first = FirstOkFrom(run, 0);
  ASSERT_NE(first, nullptr);
  ASSERT_GE(first->frame_index, 5) << "initialized without the camera moving";
  std::map<int, const PoseRecord*> pose_of;
  for (const PoseRecord& p : run.poses) pose_of[p.frame_index] = &p;
  for (int i = 0; i < first->frame_index; ++i) {
    EXPECT_EQ(run.frames[i].result.state, TrackingState::kInitializing) << i;  // as it was said then
    ASSERT_TRUE(pose_of.count(i)) << "frame " << i << " was placed in no map";
    EXPECT_EQ(pose_of[i]->submap_id, first->result.submap.value) << i;
  }
  EXPECT_TRUE(pose_of[0]->is_keyframe);
  // The hovering frames sit where the reference is, a small part of the way to the frame that
  // initialized the map (the truth: 0).
  const Eigen::Vector3d reference = pose_of[0]->world_from_cam.translation;
  const double baseline = (pose_of[first->frame_index]->world_from_cam.translation - reference).norm();
  ASSERT_GT(baseline, 0);
  for (int i = 1; i < 5; ++i) {
    if (!pose_of.count(i)) continue;
    EXPECT_LT((pose_of[i]->world_from_cam.translation - reference).norm(), 0.05 * baseline) << i;
  }
  // Frame order, and nothing placed twice.
  for (size_t k = 1; k < run.poses.size(); ++k) EXPECT_LT(run.poses[k - 1].frame_index, run.poses[k].frame_index);

  TrackingOptions without;
  without.place_initialization_frames = false;
  const InlineRun unplaced = RunScript(script, without);
  ASSERT_FALSE(unplaced.poses.empty());
  EXPECT_EQ(unplaced.poses.front().frame_index, first->frame_index);
}

TEST(TrackingLoss, ALossRightAfterAKeyframeClosesTheSubmapWithThatKeyframe) {
  // Where the clean strip makes its first keyframe after initialization (deterministic).
  std::vector<int> clean;
  Play(&clean, 0, 59);
  const InlineRun reference = RunScript(clean, "submap");
  int keyframe = -1;
  for (const auto& f : reference.frames) {
    if (f.frame_index > 3 && f.result.is_keyframe && keyframe < 0) keyframe = f.frame_index;
  }
  ASSERT_GT(keyframe, 3);

  std::vector<int> script;
  Play(&script, 0, keyframe);
  Repeat(&script, ScriptedSequence::kBlack, 5);
  Play(&script, keyframe + 6, keyframe + 60);
  const InlineRun run = RunScript(script, "submap");
  EXPECT_TRUE(run.frames[keyframe].result.is_keyframe);
  EXPECT_EQ(run.frames[keyframe + 3].result.state, TrackingState::kLost);
  EXPECT_EQ(run.submaps, 2);
  // The new submap starts at once and keeps every frame after its initialization.
  const InlineFrame* restart = FirstOkFrom(run, keyframe + 6);
  ASSERT_NE(restart, nullptr);
  EXPECT_NE(restart->result.submap, run.frames[keyframe].result.submap);
  EXPECT_LE(restart->frame_index, keyframe + 6 + 8);
  for (int i = restart->frame_index; i < static_cast<int>(script.size()); ++i) {
    EXPECT_EQ(run.frames[i].result.state, TrackingState::kOk) << i;
  }
}

TEST(TrackingLoss, TwoLossesInARowCloseOneSubmapAndBurnNoNumber) {
  std::vector<int> script;
  Play(&script, 0, 59);
  Repeat(&script, ScriptedSequence::kBlack, 5);                                  // the first failure
  for (int i = 65; i < 70; ++i) script.push_back(ScriptedSequence::Blurred(i));  // the second, at once
  Play(&script, 70, 119);
  const InlineRun run = RunScript(script, "submap");
  for (int i = 60; i < 70; ++i) EXPECT_NE(run.frames[i].result.state, TrackingState::kOk) << i;
  int closes = 0;
  for (const auto& f : run.frames) closes += f.result.state == TrackingState::kLost;
  EXPECT_EQ(closes, 1);
  std::set<int> numbers;
  for (const auto& p : run.poses) numbers.insert(SubmapNumber(SubmapId(p.submap_id)));
  EXPECT_EQ(numbers, (std::set<int>{1, 2}));
  const InlineFrame* restart = FirstOkFrom(run, 70);
  ASSERT_NE(restart, nullptr);
  EXPECT_LE(restart->frame_index, 78);
}

}  // namespace
}  // namespace stitch

namespace stitch {
namespace {

// The strip flown by a camera shaking on its mount: each frame turned about the optical axis by
// up to `amplitude_deg` (no blur), rendered at the turned pose; ground truth included.
class ShakingSequence : public ImageSequence {
 public:
  ShakingSequence(int frames, double amplitude_deg, int shake_from) {
    SyntheticOptions options;
    options.flight.num_frames = frames;
    options.flight.num_strips = 1;
    options.flight.strip_length_m = 1.15 * frames;
    synthetic_ = std::make_unique<SyntheticSequence>(options, FailureSchedule());
    renderer_ = std::make_unique<Renderer>(synthetic_->world(), synthetic_->camera());
    const Trajectory& flown = synthetic_->ground_truth();
    for (int i = 0; i < frames; ++i) {
      const int64_t t = flown.poses()[i].t_ns;
      Rigid3d world_from_cam = flown.poses()[i].world_from_cam;
      const double roll = i >= shake_from ? amplitude_deg * std::sin(2.1 * i) : 0.0;
      world_from_cam.rotation =
          world_from_cam.rotation * Eigen::Quaterniond(Eigen::AngleAxisd(roll * M_PI / 180, Eigen::Vector3d::UnitZ()));
      truth_.Add({t, world_from_cam});
    }
  }
  void Rewind() { next_ = 0; }
  std::string description() const override { return "shaking strip"; }
  int size() const override { return static_cast<int>(truth_.poses().size()); }
  const Camera& camera() const override { return synthetic_->camera(); }
  double nominal_fps() const override { return synthetic_->nominal_fps(); }
  const Trajectory& ground_truth() const override { return truth_; }
  bool Next(SequenceFrame* frame) override {
    if (next_ >= size()) return false;
    const StampedPose& pose = truth_.poses()[next_];
    frame->index = next_;
    frame->t_ns = pose.t_ns;
    frame->image = renderer_->Render(pose.world_from_cam.Inverse());
    ++next_;
    return true;
  }

 private:
  std::unique_ptr<SyntheticSequence> synthetic_;
  std::unique_ptr<Renderer> renderer_;
  Trajectory truth_;
  int next_ = 0;
};

TEST(HomographyTracking, KeepsAShakingCameraOnTrackWhereTheMotionModelGoesAstray) {
  // Roll jitter of up to 10 degrees a frame from frame 30 on: the constant-velocity guess is
  // wrong every frame, and now and then chance matches confirm a wrong pose (errors of metres).
  // Without homography tracking, with it, and with it matching only from the feature-rich cells
  // of the last frame (region of interest).
  ShakingSequence sequence(120, 10.0, 30);
  double ate[3] = {0, 0, 0};
  for (int variant = 0; variant < 3; ++variant) {
    PipelineOptions options;
    options.tracking.homography_tracking = variant > 0;
    if (variant == 2) options.tracking.homography_roi_per_cell = 6;
    sequence.Rewind();
    const InlineRun run = RunInline(sequence, options, DefaultVocabulary());
    int ok = 0, by_homography = 0;
    double homography_ms = 0;
    for (const auto& f : run.frames) {
      ok += f.result.state == TrackingState::kOk;
      if (std::string(f.result.tracked_by) != "homography") continue;
      ++by_homography;
      homography_ms += f.result.timings.frame_to_frame;
    }
    EvaluationInput input;
    input.frames_total = sequence.size();
    input.poses = run.poses;
    input.ground_truth = sequence.ground_truth();
    const Evaluation e = Evaluate(input);
    ASSERT_TRUE(e.errors);
    ate[variant] = e.errors->ate_rmse_m;
    const char* names[] = {"off", "on", "on, region of interest"};
    std::printf(
        "homography tracking %s: %d of %d frames tracked (%d placed by the homography, %.2f ms each), %d submap(s), "
        "ATE %.3f m\n",
        names[variant], ok, sequence.size(), by_homography, by_homography ? homography_ms / by_homography : 0.0,
        run.submaps, ate[variant]);
    if (variant > 0) {
      EXPECT_EQ(run.submaps, 1);
      EXPECT_GE(ok, sequence.size() - 3);  // all but the frames before initialization
      EXPECT_GT(by_homography, 20);
      EXPECT_LT(ate[variant], 0.25);  // metres, over a 138 m strip at 70 m altitude
    }
  }
  EXPECT_LE(ate[1], ate[0]);
  EXPECT_LE(ate[2], ate[1] + 0.02);  // the region of interest costs no accuracy
}

// Memory over a long flight: a submap that reaches submap_max_keyframes hands over to a new one
// that starts with copies of its local map. Tracking never breaks, the merger joins each pair on
// the copies, and the merged trajectory is as good as one map's.
TEST(SubmapHandover, AFullSubmapHandsOverWithoutABreakAndTheMergerJoinsThePieces) {
  std::vector<int> script;
  Play(&script, 0, 119);
  TrackingOptions tracking;
  tracking.submap_max_keyframes = 20;
  tracking.handover_keyframes = 5;
  tracking.closed_keyframes_held = 0;  // the tracker keeps only the last closed submap
  const InlineRun run = RunScript(script, tracking);
  int handovers = 0;
  const InlineFrame* initialized = FirstOkFrom(run, 0);
  ASSERT_NE(initialized, nullptr);
  for (size_t i = initialized->frame_index; i < run.frames.size(); ++i) {
    const TrackResult& result = run.frames[i].result;
    EXPECT_EQ(result.state, TrackingState::kOk) << "frame " << i << ": " << result.detail;
    if (i == 0 || result.submap == run.frames[i - 1].result.submap || !run.frames[i - 1].result.submap.valid()) {
      continue;
    }
    ++handovers;
    EXPECT_NE(result.detail.find("continues in submap"), std::string::npos) << result.detail;
    EXPECT_GT(result.num_tracked_points, 100) << "frame " << i << ": the copies carry the frame's points";
  }
  EXPECT_GE(handovers, 1);
  EXPECT_EQ(run.submaps, handovers + 1);
  // Every piece in one merged map...
  ASSERT_EQ(static_cast<int>(run.graph.placement.size()), run.submaps);
  for (const auto& [submap, placement] : run.graph.placement) {
    EXPECT_EQ(placement.component, run.graph.placement.begin()->second.component) << SubmapName(submap);
  }
  // ...as accurate as the strip in one map (the strip is 138 m long).
  const Evaluation e = EvaluateScript(script, run.merged_poses);
  ASSERT_TRUE(e.errors);
  EXPECT_EQ(e.frames_localized, 120);
  EXPECT_LT(e.errors->ate_rmse_m, 0.3);
  std::printf("handed over %d times: ATE %.3f m (max %.3f m)\n", handovers, e.errors->ate_rmse_m, e.errors->ate_max_m);
}

}  // namespace
}  // namespace stitch
