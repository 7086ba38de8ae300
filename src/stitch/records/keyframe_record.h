#pragma once
// keyframes.tsv: the mapper's final keyframe poses, culled keyframes included (placed through
// their parents). Written by the mapper service when it stops, read by `stitch run` / `stitch
// eval` and by the tests that check what reached the merger.

#include <cstdint>
#include <string>
#include <vector>

#include "stitch/geometry/rigid3.h"

namespace stitch {

struct KeyframeRecord {
  int64_t keyframe_id = -1;
  int64_t submap_id = -1;
  int frame_index = -1;
  int64_t t_ns = 0;
  bool culled = false;
  Rigid3d world_from_cam;  // in the submap's frame
};

// The whole file, replaced as one act. Throws stitch::Error naming the file.
void WriteKeyframeRecords(const std::string& path, const std::vector<KeyframeRecord>& records);
std::string KeyframeRecordHeader();                              // "# ..." line, with newline
std::string FormatKeyframeRecord(const KeyframeRecord& record);  // one line, with newline
// Throws stitch::Error naming the file and line for a malformed record or an unreadable file.
std::vector<KeyframeRecord> ReadKeyframeRecords(const std::string& path);

}  // namespace stitch
