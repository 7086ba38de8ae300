#include "stitch/pipeline/inline_pipeline.h"

#include <algorithm>
#include <map>

#include "stitch/merging/frame_trajectory.h"
#include "stitch/merging/merge_session.h"
#include "stitch/util/time.h"

namespace stitch {

InlineRun RunInline(ImageSequence& sequence, const PipelineOptions& options, const Vocabulary& vocabulary,
                    const std::function<void(const InlineFrame&)>& on_frame, bool keep_submap_updates) {
  Tracking tracking(options.tracking, sequence.camera(), &vocabulary, sequence.nominal_fps(),
                    ParseLossPolicy(options.on_loss));
  LocalMapping mapping(options.mapping, sequence.camera(), options.tracking.orb, &vocabulary);
  MergeSession merging(options.merger, &vocabulary, ScalePyramid::From(options.tracking.orb));
  InlineRun run;
  const auto send = [&](const SubmapUpdate& update) {
    merging.Apply(update, /*agent=*/"", /*first_part=*/true);  // nothing is split or lost inline
    // A closed submap's final state refines the merged maps, as the merger service does.
    if (update.closed && update.full_state && merging.FirstWholeFinalState(update.submap)) {
      merging.Refine("submap " + SubmapName(update.submap) + " closed");
    }
    if (keep_submap_updates) run.submap_updates.push_back(update);
  };
  const auto close_submap = [&]() {
    if (const auto closed = mapping.CloseSubmap()) send(mapping.MakeFinalSubmapUpdate(*closed));
  };
  std::map<int64_t, int> component_of;
  std::vector<TrackedFramePose> tracked;  // as the pose stream carries them
  const auto add_pose = [&](int frame_index, int64_t t_ns, const TrackResult& result) {
    if (result.state != TrackingState::kOk || !result.cam_from_submap) return;
    tracked.push_back({frame_index, t_ns, result.submap.value, result.is_keyframe, result.cam_from_submap->Inverse(),
                       result.cam_from_reference ? result.reference_keyframe.value : -1,
                       result.cam_from_reference.value_or(Rigid3d())});
    const int64_t submap = result.submap.value;
    component_of.try_emplace(submap, static_cast<int>(component_of.size()));
    PoseRecord pose;
    pose.frame_index = frame_index;
    pose.t_ns = t_ns;
    pose.submap_id = submap;
    pose.component = component_of[submap];
    pose.is_keyframe = result.is_keyframe;
    pose.world_from_cam = result.cam_from_submap->Inverse();
    run.poses.push_back(pose);
  };
  SequenceFrame frame;
  while (sequence.Next(&frame)) {
    InlineFrame done;
    done.frame_index = frame.index;
    done.t_ns = frame.t_ns;
    if (frame.image.empty()) {
      done.result.state = TrackingState::kSkipped;
      done.result.reason = TrackingReason::kUndecodableFrame;
      done.result.detail = frame.error;
    } else {
      Tracking::Output output = tracking.Track(frame.image, frame.index, frame.t_ns);
      if (output.closed_submap && mapping.map() && mapping.map()->id() == *output.closed_submap) close_submap();
      for (size_t k = 0; k < output.new_keyframes.size(); ++k) {
        const Stopwatch mapping_clock;
        MappedKeyframe mapped =
            mapping.MapKeyframe(output.new_keyframes[k], k == 0 ? output.new_points : std::vector<MapPoint>());
        done.mapping_ms += mapping_clock.ElapsedMs();
        done.mapped.push_back(mapped.report);
        const Stopwatch merger_clock;
        if (mapped.closed_final) send(*mapped.closed_final);
        tracking.ApplyUpdate(mapped.for_tracker);
        if (mapped.for_merger.submap.valid()) send(mapped.for_merger);
        done.merger_ms += merger_clock.ElapsedMs();
        ++run.keyframes;
      }
      done.result = std::move(output.result);
      for (const Tracking::EarlierFrame& earlier : output.earlier_frames) {
        add_pose(earlier.frame_index, earlier.t_ns, earlier.result);
      }
    }
    add_pose(frame.index, frame.t_ns, done.result);
    if (on_frame) on_frame(done);
    run.frames.push_back(std::move(done));
  }
  // In frame order (the frames a map initialized from come after it).
  std::stable_sort(run.poses.begin(), run.poses.end(),
                   [](const PoseRecord& a, const PoseRecord& b) { return a.frame_index < b.frame_index; });
  std::stable_sort(tracked.begin(), tracked.end(),
                   [](const TrackedFramePose& a, const TrackedFramePose& b) { return a.frame_index < b.frame_index; });
  run.submaps = static_cast<int>(component_of.size());
  close_submap();
  merging.Finish();
  run.graph = merging.refined()->graph;
  // As `stitch run` places them at the end: each frame re-composed with the mapper's final pose
  // of its reference keyframe (culled ones included), placed by the merger and moved with the
  // refinement's keyframe poses.
  std::map<int64_t, KeyframeInSubmap> keyframes;
  for (const auto& map : mapping.closed_maps()) {
    for (const auto& [id, keyframe] : map->keyframes())
      keyframes[id.value] = {keyframe.cam_from_world, keyframe.frame_index};
  }
  for (const CulledKeyframe& culled : mapping.CulledKeyframePoses()) {
    keyframes[culled.id.value] = {culled.cam_from_world, culled.frame_index};
  }
  std::map<int64_t, SubmapInMap> placement;
  for (const auto& [id, p] : run.graph.placement) placement[id.value] = {p.component, p.world_from_submap};
  std::map<int64_t, Sim3d> refined;
  for (const auto& [id, pose] : run.graph.keyframe_poses) refined[id.value] = pose;
  for (const PoseRecord& pose : PlaceTrackedFrames(tracked, keyframes, placement, refined)) {
    if (pose.component >= 0) run.merged_poses.push_back(pose);
  }
  return run;
}

}  // namespace stitch
