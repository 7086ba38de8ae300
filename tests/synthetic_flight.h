#pragma once
// For tests that fly the synthetic survey through the ingest service, as `stitch run` does.

#include <atomic>
#include <string>

#include "services/ingest/ingest_service.h"
#include "stitch/io/trajectory.h"
#include "stitch/source/source.h"

namespace stitch::testing {

// Plays the synthetic flight `synthetic` with `failures` (a --failures schedule) through
// `ingest`, lockstep; `max_frames` < 0: all of it. `ground_truth` (optional) receives its truth.
inline IngestSummary PlaySyntheticFlight(IngestService& ingest, const SyntheticOptions& synthetic,
                                         const std::string& failures, int max_frames = -1,
                                         Trajectory* ground_truth = nullptr) {
  SourceSpec spec;
  spec.synthetic = synthetic;
  spec.failures = failures;
  spec.max_frames = max_frames;
  FailureSchedule spoil;
  auto sequence = OpenSource(spec, &spoil);
  if (ground_truth) *ground_truth = sequence->ground_truth();
  std::atomic<bool> stop{false};
  return ingest.Play(*sequence, spoil, stop);
}

}  // namespace stitch::testing
