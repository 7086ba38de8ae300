#include "stitch/records/frame_record.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <map>
#include <sstream>

#include "stitch/io/trajectory.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "stitch/util/text_file.h"

namespace stitch {
namespace {

// `text` on one line of single spaces: no line break or tab of a message ends a record early.
std::string OneLine(const std::string& text) {
  std::string line;
  for (char c : text) {
    const bool space = c == '\n' || c == '\r' || c == '\t' || c == ' ';
    if (space && (line.empty() || line.back() == ' ')) continue;
    line += space ? ' ' : c;
  }
  while (!line.empty() && line.back() == ' ') line.pop_back();
  return line;
}

}  // namespace

std::string FrameRecordHeader() {
  return "# frame_index t_ns state reason submap_id tx ty tz qx qy qz qw num_features tracked_points keyframe "
         "tracking_ms reference_keyframe rtx rty rtz rqx rqy rqz rqw note (pose: world_from_cam in the submap's frame; "
         "r*: reference_from_cam; note: the tracker's words, to the line's end)\n";
}

std::string FormatFrameRecord(const FrameRecord& r) {
  char counts[64];
  std::snprintf(counts, sizeof(counts), " %d %d %d %.3f ", r.num_features, r.tracked_points, r.is_keyframe ? 1 : 0,
                r.tracking_ms);
  return std::to_string(r.frame_index) + " " + std::to_string(r.t_ns) + " " + r.state + " " + std::to_string(r.reason) +
         " " + std::to_string(r.submap_id) + " " + FormatTumPose(r.world_from_cam) + counts +
         std::to_string(r.reference_keyframe) + " " + FormatTumPose(r.cam_from_reference.Inverse()) +
         (r.note.empty() ? "" : " " + OneLine(r.note)) + "\n";
}

std::vector<FrameRecord> ReadFrameRecords(const std::string& path) {
  std::vector<FrameRecord> records;
  std::map<int, size_t> line_of;  // frame index -> its record
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
    std::getline(fields >> std::ws, r.note);
    r.is_keyframe = keyframe != 0;
    r.cam_from_reference = reference_from_cam.Inverse();
    const auto [seen, first] = line_of.try_emplace(r.frame_index, records.size());
    if (first) {
      records.push_back(r);
      return;
    }
    FrameRecord& earlier = records[seen->second];
    if (r.tracking_ms == 0) {  // placed after the fact: the frame was tracked (and timed) before
      r.tracking_ms = earlier.tracking_ms;
      r.num_features = earlier.num_features;
    }
    earlier = r;
  });
  return records;
}

std::ofstream AppendToFrameRecord(const std::string& path) {
  std::error_code error;
  const uintmax_t size = std::filesystem::exists(path, error) ? std::filesystem::file_size(path, error) : 0;
  if (error) throw Error(path + ": cannot read the frame record: " + error.message());
  uintmax_t kept = size;
  if (size > 0) {
    // Only the tail matters: a record line is a few hundred bytes.
    const uintmax_t tail_size = std::min<uintmax_t>(size, 1 << 16);
    std::string tail(tail_size, '\0');
    std::ifstream in(path, std::ios::binary);
    in.seekg(static_cast<std::streamoff>(size - tail_size));
    if (!in.read(tail.data(), static_cast<std::streamsize>(tail_size)))
      throw Error(path + ": cannot read the frame record");
    if (tail.back() != '\n') {
      const size_t newline = tail.rfind('\n');
      if (newline == std::string::npos && tail_size < size)
        throw Error(path + ": not a frame record (no line ends in its last 64 KiB)");
      kept = size - tail_size + (newline == std::string::npos ? 0 : newline + 1);
      std::filesystem::resize_file(path, kept, error);
      if (error) throw Error(path + ": cannot drop the frame record's unfinished last line: " + error.message());
      STITCH_LOG(WARNING) << path << ": dropped an unfinished last line (" << size - kept
                          << " bytes; the tracker writing it was stopped mid-line)";
    }
  }
  std::ofstream out(path, std::ios::app);
  if (!out) throw Error(path + ": cannot write the frame record");
  if (kept == 0) out << FrameRecordHeader() << std::flush;
  return out;
}

}  // namespace stitch
