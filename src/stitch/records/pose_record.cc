#include "stitch/records/pose_record.h"

#include <algorithm>
#include <map>
#include <set>
#include <sstream>

#include "stitch/io/trajectory.h"
#include "stitch/util/error.h"
#include "stitch/util/ids.h"
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

std::string RunMap::SubmapNames() const {
  std::string names;
  for (int64_t submap : submaps) names += (names.empty() ? "" : ",") + SubmapName(SubmapId(submap));
  return names;
}

std::vector<RunMap> MapsOfRun(const std::vector<PoseRecord>& poses, int largest_component) {
  std::map<int, RunMap> by_component;
  std::map<int, std::set<int64_t>> submaps;
  for (const auto& p : poses) {
    RunMap& map = by_component[p.component];
    map.component = p.component;
    ++map.frames;
    submaps[p.component].insert(p.submap_id);
  }
  std::vector<RunMap> maps;
  for (auto& [component, map] : by_component) {
    map.submaps.assign(submaps[component].begin(), submaps[component].end());
    map.largest = component == largest_component;
    maps.push_back(map);
  }
  std::stable_sort(maps.begin(), maps.end(), [](const RunMap& a, const RunMap& b) {
    if (a.largest != b.largest) return a.largest;
    return a.frames > b.frames;
  });
  int merged_maps = 0;
  for (RunMap& map : maps) {
    if (map.submaps.size() > 1) {
      map.name = "map-" + std::to_string(merged_maps++);
    } else {
      map.name = "submap-" + SubmapName(SubmapId(map.submaps.front()));
      std::replace(map.name.begin(), map.name.end(), ':', '-');
    }
  }
  return maps;
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
