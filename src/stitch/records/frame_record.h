#pragma once
// frames.tsv: the tracker's line per frame (state, why, submap, pose, counts, time). Written by
// the tracker service as it goes, read by `stitch run` / `stitch eval` to build the outputs.

#include <cstdint>
#include <fstream>
#include <string>
#include <vector>

#include "stitch/geometry/rigid3.h"

namespace stitch {

struct FrameRecord {
  int frame_index = -1;
  int64_t t_ns = 0;
  std::string state;  // INITIALIZING, OK, LOST, SKIPPED, NOT_TRACKED
  int reason = 0;     // tracking_status_t REASON_* value
  int64_t submap_id = -1;
  Rigid3d world_from_cam;           // in the submap's frame; meaningful when state == "OK"
  int64_t reference_keyframe = -1;  // keyframe the pose was tracked against (-1: none)
  Rigid3d cam_from_reference;       // the pose relative to that keyframe
  int num_features = 0;
  int tracked_points = 0;
  bool is_keyframe = false;
  double tracking_ms = 0;
  // The tracker's word on the frame where it has one (why it was not tracked, how a map
  // initialized: model, score share, parallax, points, refusals); one line, no tabs. Last column;
  // records written before it had none.
  std::string note;
};

std::string FrameRecordHeader();                           // "# ..." line, with newline
std::string FormatFrameRecord(const FrameRecord& record);  // one line, with newline
// One record per frame, in the order of each frame's first line: a frame may have a later line
// (a new map placed the frames it initialized from once it existed, or missed frames were placed
// backward from a later one; a restarted tracker tracked an unacknowledged frame again), which
// replaces the first, keeping the first's tracking time and feature count where the later one has
// none. Throws stitch::Error naming the line for a malformed record.
std::vector<FrameRecord> ReadFrameRecords(const std::string& path);
// Opens a record to add lines to (a restarted tracker goes on with the same file): a new or empty
// file gets the header; an existing one keeps its records, less a last line cut short by a writer
// killed mid-line (that frame was never acknowledged, so it is tracked and recorded again).
// Throws stitch::Error when the file cannot be read or written.
std::ofstream AppendToFrameRecord(const std::string& path);

}  // namespace stitch
