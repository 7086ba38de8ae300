#pragma once
// The tracker, mapper and merger algorithms run one after the other in the calling thread, with
// no transport between them: each keyframe is mapped (LocalMapping::MapKeyframe, the protocol the
// mapper service follows) and its update applied before the next frame, exactly what lockstep
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
  double mapping_ms = 0;                 // mapping the keyframes this frame made (0 if none), in all
  std::vector<MappingReport> mapped;     // ...one by one
  double merger_ms = 0;                  // the merger taking them, and the tracker their updates
};

struct InlineRun {
  std::vector<InlineFrame> frames;
  std::vector<PoseRecord> poses;             // the tracker's poses, each submap its own component
  std::vector<PoseRecord> merged_poses;      // the same, placed by the merger's Sim3 per submap (no pose graph)
  Merger::Graph graph;                       // the merger's submap graph at the end
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
