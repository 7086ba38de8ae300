#include "stitch/records/pose_record.h"

#include <sstream>

#include "stitch/io/trajectory.h"
#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace stitch {

std::vector<PoseRecord> ReadPoseRecords(const std::string& path) {
  std::vector<PoseRecord> poses;
  ForEachDataLine(path, [&](const std::string& line, int line_number) {
    std::istringstream fields(line);
    PoseRecord p;
    int keyframe = 0;
    fields >> p.frame_index >> p.t_ns >> p.submap_id >> p.component >> keyframe;
    if (!fields || !ReadTumPose(fields, &p.world_from_cam)) {
      throw Error(Str() << path << ":" << line_number << ": malformed pose record");
    }
    p.is_keyframe = keyframe != 0;
    poses.push_back(p);
  });
  return poses;
}

void WritePoseRecords(const std::string& path, const std::vector<PoseRecord>& poses) {
  std::ostringstream out;
  out << "# frame_index t_ns submap_id component keyframe tx ty tz qx qy qz qw (world_from_cam)\n";
  for (const auto& p : poses) {
    out << p.frame_index << " " << p.t_ns << " " << p.submap_id << " " << p.component << " " << (p.is_keyframe ? 1 : 0)
        << " " << FormatTumPose(p.world_from_cam) << "\n";
  }
  WriteFileAtomically(path, out.str());
}

}  // namespace stitch
