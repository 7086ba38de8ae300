#include "stitch/eval/frame_record.h"

#include <cstdio>
#include <sstream>

#include "stitch/io/trajectory.h"
#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace stitch {

std::string FrameRecordHeader() {
  return "# frame_index t_ns state reason submap_id tx ty tz qx qy qz qw num_features tracked_points keyframe "
         "tracking_ms reference_keyframe rtx rty rtz rqx rqy rqz rqw (pose: world_from_cam in the submap's frame; "
         "r*: reference_from_cam)\n";
}

std::string FormatFrameRecord(const FrameRecord& r) {
  char counts[64];
  std::snprintf(counts, sizeof(counts), " %d %d %d %.3f ", r.num_features, r.tracked_points, r.is_keyframe ? 1 : 0,
                r.tracking_ms);
  return std::to_string(r.frame_index) + " " + std::to_string(r.t_ns) + " " + r.state + " " + std::to_string(r.reason) +
         " " + std::to_string(r.submap_id) + " " + FormatTumPose(r.world_from_cam) + counts +
         std::to_string(r.reference_keyframe) + " " + FormatTumPose(r.cam_from_reference.Inverse()) + "\n";
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
    fields >> r.num_features >> r.tracked_points >> keyframe >> r.tracking_ms >> r.reference_keyframe;
    Rigid3d reference_from_cam;
    const bool relative = fields && ReadTumPose(fields, &reference_from_cam);
    if (!pose || !relative) {
      truncated = true;  // acceptable only as the last line: a killed tracker may cut it short
      return;
    }
    r.is_keyframe = keyframe != 0;
    r.cam_from_reference = reference_from_cam.Inverse();
    records.push_back(r);
  });
  return records;
}

}  // namespace stitch
