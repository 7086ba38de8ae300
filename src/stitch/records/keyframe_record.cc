#include "stitch/records/keyframe_record.h"

#include <sstream>

#include "stitch/io/trajectory.h"
#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace stitch {

std::string KeyframeRecordHeader() {
  return "# keyframe_id submap_id frame_index t_ns culled tx ty tz qx qy qz qw (world_from_cam in the submap's "
         "frame)\n";
}

std::string FormatKeyframeRecord(const KeyframeRecord& r) {
  return std::to_string(r.keyframe_id) + " " + std::to_string(r.submap_id) + " " + std::to_string(r.frame_index) + " " +
         std::to_string(r.t_ns) + (r.culled ? " 1 " : " 0 ") + FormatTumPose(r.world_from_cam) + "\n";
}

void WriteKeyframeRecords(const std::string& path, const std::vector<KeyframeRecord>& records) {
  std::string text = KeyframeRecordHeader();
  for (const KeyframeRecord& r : records) text += FormatKeyframeRecord(r);
  WriteFileAtomically(path, text);
}

std::vector<KeyframeRecord> ReadKeyframeRecords(const std::string& path) {
  std::vector<KeyframeRecord> records;
  ForEachDataLine(path, [&](const std::string& line, int line_number) {
    std::istringstream fields(line);
    KeyframeRecord r;
    int culled = 0;
    fields >> r.keyframe_id >> r.submap_id >> r.frame_index >> r.t_ns >> culled;
    if (!fields || !ReadTumPose(fields, &r.world_from_cam)) {
      throw Error(Str() << path << ":" << line_number << ": malformed keyframe record");
    }
    r.culled = culled != 0;
    records.push_back(r);
  });
  return records;
}

}  // namespace stitch
