#include "stitch/eval/frame_record.h"

#include <cstdio>
#include <sstream>

#include "stitch/io/trajectory.h"
#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace stitch {

std::string FrameRecordHeader() {
  return "# frame_index t_ns state reason submap_id tx ty tz qx qy qz qw num_features tracked_points keyframe "
         "tracking_ms (pose: world_from_cam in the submap's frame)\n";
}

std::string FormatFrameRecord(const FrameRecord& r) {
  char tail[64];
  std::snprintf(tail, sizeof(tail), " %d %d %d %.3f\n", r.num_features, r.tracked_points, r.is_keyframe ? 1 : 0,
                r.tracking_ms);
  return std::to_string(r.frame_index) + " " + std::to_string(r.t_ns) + " " + r.state + " " + std::to_string(r.reason) +
         " " + std::to_string(r.submap_id) + " " + FormatTumPose(r.world_from_cam) + tail;
}

std::vector<FrameRecord> ReadFrameRecords(const std::string& path) {
  std::vector<FrameRecord> records;
  bool truncated = false;
  ForEachDataLine(path, [&](const std::string& line, int line_number) {
    if (truncated) throw Error(Str() << path << ":" << line_number - 1 << ": malformed frame record");
    std::istringstream fields(line);
    FrameRecord r;
    int keyframe = 0;
    fields >> r.frame_index >> r.t_ns >> r.state >> r.reason >> r.submap_id;
    const bool pose = fields && ReadTumPose(fields, &r.world_from_cam);
    fields >> r.num_features >> r.tracked_points >> keyframe >> r.tracking_ms;
    if (!pose || !fields) {
      truncated = true;  // acceptable only as the last line: a killed tracker may cut it short
      return;
    }
    r.is_keyframe = keyframe != 0;
    records.push_back(r);
  });
  return records;
}

}  // namespace stitch
