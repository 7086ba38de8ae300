#include "stitch/pipeline/inline_pipeline.h"

#include <algorithm>
#include <map>

#include "stitch/util/time.h"

namespace stitch {

InlineRun RunInline(ImageSequence& sequence, const PipelineOptions& options, const Vocabulary& vocabulary,
                    const std::function<void(const InlineFrame&)>& on_frame, bool keep_submap_updates) {
  Tracking tracking(options.tracking, sequence.camera(), &vocabulary, sequence.nominal_fps(),
                    ParseLossPolicy(options.on_loss));
  LocalMapping mapping(options.mapping, sequence.camera(), options.tracking.orb, &vocabulary);
  Merger merger(options.merger, &vocabulary, ScalePyramid::From(options.tracking.orb));
  InlineRun run;
  const auto send = [&](const SubmapUpdate& update) {
    merger.Apply(update);
    if (keep_submap_updates) run.submap_updates.push_back(update);
  };
  const auto close_submap = [&]() {
    if (const auto closed = mapping.CloseSubmap()) send(mapping.MakeFinalSubmapUpdate(*closed));
  };
  std::map<int64_t, int> component_of;
  const auto add_pose = [&](int frame_index, int64_t t_ns, const TrackResult& result) {
    if (result.state != TrackingState::kOk || !result.cam_from_submap) return;
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
  run.submaps = static_cast<int>(component_of.size());
  close_submap();
  run.graph = merger.Solve();
  for (const PoseRecord& pose : run.poses) {
    const auto placed = run.graph.placement.find(SubmapId(pose.submap_id));
    if (placed == run.graph.placement.end()) continue;
    PoseRecord merged = pose;
    merged.component = placed->second.component;
    merged.world_from_cam = TransformPose(placed->second.world_from_submap, pose.world_from_cam);
    run.merged_poses.push_back(merged);
  }
  return run;
}

}  // namespace stitch
