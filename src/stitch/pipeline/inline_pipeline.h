#pragma once
// The tracker, mapper and merger algorithms run one after the other in the calling thread, with
// no transport between them: each keyframe is mapped (LocalMapping::MapKeyframe, the protocol the
// mapper service follows) and its update applied to the merger's session (MergeSession, as the
// merger service applies it, refinement included) before the next frame, exactly what lockstep
// pacing with `wait_for_mapper` gives over the bus. For benchmarks (stitch bench: the same work,
// timed without the bus) and for tests of the SLAM core on whole sequences. No LCM.

#include <functional>
#include <string>
#include <vector>

#include "stitch/eval/evaluation.h"
#include "stitch/io/image_sequence.h"
#include "stitch/mapping/local_mapping.h"
#include "stitch/merging/merger.h"
#include "stitch/pipeline/pipeline_options.h"
#include "stitch/tracking/tracking.h"

namespace stitch {

struct InlineFrame {
  int frame_index = -1;
  int64_t t_ns = 0;
  TrackResult result;
  double mapping_ms = 0;              // mapping the keyframes this frame made (0 if none), in all
  std::vector<MappingReport> mapped;  // ...one by one
  double merger_ms = 0;               // the merger taking them, and the tracker their updates
};

struct InlineRun {
  std::vector<InlineFrame> frames;
  std::vector<PoseRecord> poses;  // the tracker's poses, each submap its own component
  // The same, each re-composed with the mapper's final pose of its reference keyframe and placed
  // in its merged map with the merger's refinement (pose graph, bundle adjustment), as `stitch
  // run` places frames.tsv; frames of submaps the merger never placed are left out.
  std::vector<PoseRecord> merged_poses;
  Merger::Graph graph;                       // the merger's submap graph at the end, refined
  std::vector<SubmapUpdate> submap_updates;  // what the mapper sent the merger, in order (when asked)
  int keyframes = 0;                         // keyframes made
  int submaps = 0;
};

// Plays `sequence` through the tracker, mapper and merger; `on_frame` (optional) sees every
// frame as it is done. Throws stitch::Error on invalid settings.
InlineRun RunInline(ImageSequence& sequence, const PipelineOptions& options, const Vocabulary& vocabulary,
                    const std::function<void(const InlineFrame&)>& on_frame = nullptr,
                    bool keep_submap_updates = false);

}  // namespace stitch
