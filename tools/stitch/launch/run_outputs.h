#pragma once
// The outputs of a run folder, built from what the services wrote into it:
//   frames.tsv (tracker), poses.tsv and map.ply (when a merger / mapper wrote them),
//   groundtruth.tum and run.json (launcher)
// become trajectory.tum, poses.tsv, map.ply, report.json and trajectory.png. `stitch run` calls
// this at the end; `stitch eval RUN_DIR` calls it again on a finished folder.

#include <string>
#include <vector>

#include "stitch/eval/evaluation.h"
#include "stitch/records/run_info.h"

namespace stitch {

// Builds the outputs listed above; adds to `info.notes` what a reader must know (an empty map, a
// tracker without SLAM core). Returns the evaluation also written to report.json.
Evaluation FinishRunOutputs(const std::string& run_dir, RunInfo* info);

}  // namespace stitch
