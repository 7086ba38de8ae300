#include "stitch/records/merger_records.h"

#include <algorithm>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <functional>
#include <map>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include "stitch/io/image_file.h"
#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace stitch {
namespace {

// A Sim3 as "scale qx qy qz qw tx ty tz", 9 significant digits.
std::string FormatSim3(const Sim3d& s) {
  char text[200];
  std::snprintf(text, sizeof(text), "%.9g %.9g %.9g %.9g %.9g %.9g %.9g %.9g", s.scale, s.rotation.x(), s.rotation.y(),
                s.rotation.z(), s.rotation.w(), s.translation.x(), s.translation.y(), s.translation.z());
  return text;
}

bool ReadSim3(std::istream& fields, Sim3d* s) {
  double scale, qx, qy, qz, qw, tx, ty, tz;
  fields >> scale >> qx >> qy >> qz >> qw >> tx >> ty >> tz;
  if (!fields) return false;
  *s = Sim3d(scale, Eigen::Quaterniond(qw, qx, qy, qz).normalized(), Eigen::Vector3d(tx, ty, tz));
  return true;
}

// Reads every data line of `path` with `parse`, which returns false for a malformed line.
template <class Record, class Parse>
std::vector<Record> ReadLines(const std::string& path, const char* what, Parse parse) {
  std::vector<Record> records;
  ForEachDataLine(path, [&](const std::string& line, int line_number) {
    Record record;
    if (!parse(line, &record)) throw Error(Str() << path << ":" << line_number << ": malformed " << what);
    records.push_back(std::move(record));
  });
  return records;
}

std::vector<std::string> SplitTabs(const std::string& line) {
  std::vector<std::string> fields;
  size_t start = 0;
  while (true) {
    const size_t tab = line.find('\t', start);
    fields.push_back(line.substr(start, tab == std::string::npos ? std::string::npos : tab - start));
    if (tab == std::string::npos) return fields;
    start = tab + 1;
  }
}

std::string FormatIds(const std::vector<KeyframeId>& ids) {
  std::string text;
  for (KeyframeId id : ids) text += (text.empty() ? "" : ",") + std::to_string(id.value);
  return text.empty() ? std::string("-") : text;
}

bool ParseIds(const std::string& text, std::vector<KeyframeId>* ids) {
  ids->clear();
  if (text == "-") return true;
  std::istringstream list(text);
  for (std::string item; std::getline(list, item, ',');) {
    char* end = nullptr;
    const long long value = std::strtoll(item.c_str(), &end, 10);
    if (item.empty() || *end != '\0') return false;
    ids->push_back(KeyframeId(value));
  }
  return true;
}

}  // namespace

void WriteSubmapRecords(const std::string& path, const std::vector<SubmapRecord>& records) {
  std::string text =
      "# submap_id component root keyframes points closed scale qx qy qz qw tx ty tz (world_from_submap)\n";
  for (const SubmapRecord& r : records) {
    char head[160];
    std::snprintf(head, sizeof(head), "%" PRId64 " %d %" PRId64 " %zu %zu %d ", r.submap.value, r.component,
                  r.root.value, r.keyframes, r.points, r.closed ? 1 : 0);
    text += head + FormatSim3(r.world_from_submap) + "\n";
  }
  WriteFileAtomically(path, text);
}

std::vector<SubmapRecord> ReadSubmapRecords(const std::string& path) {
  return ReadLines<SubmapRecord>(path, "submap record", [](const std::string& line, SubmapRecord* r) {
    std::istringstream fields(line);
    int closed = 0;
    fields >> r->submap.value >> r->component >> r->root.value >> r->keyframes >> r->points >> closed;
    r->closed = closed != 0;
    return fields && ReadSim3(fields, &r->world_from_submap);
  });
}

void WriteMergedKeyframeRecords(const std::string& path, const std::vector<MergedKeyframeRecord>& records) {
  std::string text =
      "# keyframe_id submap_id component scale qx qy qz qw tx ty tz (world_from_cam, refined by the pose graph) "
      "frame_index t_ns\n";
  for (const MergedKeyframeRecord& r : records) {
    char head[100], tail[64];
    std::snprintf(head, sizeof(head), "%" PRId64 " %" PRId64 " %d ", r.keyframe.value, SubmapOf(r.keyframe).value,
                  r.component);
    std::snprintf(tail, sizeof(tail), " %d %" PRId64 "\n", r.frame_index, r.t_ns);
    text += head + FormatSim3(r.world_from_cam) + tail;
  }
  WriteFileAtomically(path, text);
}

std::vector<MergedKeyframeRecord> ReadMergedKeyframeRecords(const std::string& path) {
  return ReadLines<MergedKeyframeRecord>(path, "merged keyframe", [](const std::string& line, MergedKeyframeRecord* r) {
    std::istringstream fields(line);
    int64_t submap = -1;
    fields >> r->keyframe.value >> submap >> r->component;
    if (!fields || submap != SubmapOf(r->keyframe).value || !ReadSim3(fields, &r->world_from_cam)) return false;
    if (!(fields >> r->frame_index)) return fields.eof();  // a file from before the timestamps
    return static_cast<bool>(fields >> r->t_ns);
  });
}

void WriteConnectionRecords(const std::string& path, const std::vector<ConnectionRecord>& records) {
  std::string text =
      "# keyframe_a keyframe_b map_points median_angle_deg scale qx qy qz qw tx ty tz (b_from_a: submap b's frame from "
      "a's; loops within one submap last) verified_by bearing_spread_a bearing_spread_b line_ratio depth_disagreement "
      "verdict (the rest of the line)\n";
  for (const ConnectionRecord& r : records) {
    char head[120], tail[200];
    std::snprintf(head, sizeof(head), "%" PRId64 " %" PRId64 " %d %.3f ", r.keyframe_a.value, r.keyframe_b.value,
                  r.map_points, r.median_angle_deg);
    std::snprintf(tail, sizeof(tail), " %s %.4f %.4f %.4f %.4f ", r.verified_by.c_str(), r.bearing_spread_a,
                  r.bearing_spread_b, r.line_ratio, r.depth_disagreement);
    text += head + FormatSim3(r.b_from_a) + tail + r.verdict + "\n";
  }
  WriteFileAtomically(path, text);
}

std::vector<ConnectionRecord> ReadConnectionRecords(const std::string& path) {
  return ReadLines<ConnectionRecord>(path, "connection", [](const std::string& line, ConnectionRecord* r) {
    std::istringstream fields(line);
    fields >> r->keyframe_a.value >> r->keyframe_b.value >> r->map_points >> r->median_angle_deg;
    if (!fields || !ReadSim3(fields, &r->b_from_a)) return false;
    fields >> r->verified_by >> r->bearing_spread_a >> r->bearing_spread_b >> r->line_ratio >> r->depth_disagreement;
    if (!fields) return false;
    std::getline(fields >> std::ws, r->verdict);
    return !r->verdict.empty();
  });
}

void WriteSubmapEdgeRecords(const std::string& path, const std::vector<SubmapEdgeRecord>& records) {
  std::string text =
      "# submap_a submap_b strength connected_frames map_points disagreeing_frames median_angle_deg agreement status "
      "(the rest of the line)\n";
  for (const SubmapEdgeRecord& r : records) {
    char head[200];
    std::snprintf(head, sizeof(head), "%" PRId64 " %" PRId64 " %.3f %d %d %d %.3f %.4f ", r.a.value, r.b.value,
                  r.strength, r.connected_frames, r.map_points, r.disagreeing_frames, r.median_angle_deg, r.agreement);
    text += head + r.status + "\n";
  }
  WriteFileAtomically(path, text);
}

std::vector<SubmapEdgeRecord> ReadSubmapEdgeRecords(const std::string& path) {
  return ReadLines<SubmapEdgeRecord>(path, "submap edge", [](const std::string& line, SubmapEdgeRecord* r) {
    std::istringstream fields(line);
    fields >> r->a.value >> r->b.value >> r->strength >> r->connected_frames >> r->map_points >>
        r->disagreeing_frames >> r->median_angle_deg >> r->agreement;
    if (!fields) return false;
    std::getline(fields >> std::ws, r->status);
    return !r->status.empty();
  });
}

void WriteRetrievalRecords(const std::string& path, const std::vector<RetrievalRecord>& records) {
  std::string text =
      "# keyframe previous nearby N0 N1 S0 S1 k l shared_word_candidates candidates connected "
      "verification(matches/inliers per candidate) loop_candidates loops skipped\n";
  for (const RetrievalRecord& r : records) {
    char numbers[200];
    std::snprintf(numbers, sizeof(numbers), "%d\t%d\t%.4f\t%.4f\t%.3f\t%.3f\t%d", r.n0, r.n1, r.s0, r.s1, r.k, r.l,
                  r.shared_word_candidates);
    std::string verification;
    for (const auto& [matches, inliers] : r.verification) {
      verification += (verification.empty() ? "" : ",") + std::to_string(matches) + "/" + std::to_string(inliers);
    }
    text += std::to_string(r.keyframe.value) + "\t" + std::to_string(r.previous.value) + "\t" +
            std::to_string(r.nearby.value) + "\t" + numbers + "\t" + FormatIds(r.candidates) + "\t" +
            FormatIds(r.connected) + "\t" + (verification.empty() ? "-" : verification) + "\t" +
            FormatIds(r.loop_candidates) + "\t" + FormatIds(r.loops) + "\t" + (r.skipped.empty() ? "-" : r.skipped) +
            "\n";
  }
  WriteFileAtomically(path, text);
}

std::vector<RetrievalRecord> ReadRetrievalRecords(const std::string& path) {
  return ReadLines<RetrievalRecord>(path, "retrieval record", [](const std::string& line, RetrievalRecord* r) {
    const std::vector<std::string> f = SplitTabs(line);
    if (f.size() != 16) return false;
    std::istringstream numbers(f[0] + " " + f[1] + " " + f[2] + " " + f[3] + " " + f[4] + " " + f[5] + " " + f[6] +
                               " " + f[7] + " " + f[8] + " " + f[9]);
    numbers >> r->keyframe.value >> r->previous.value >> r->nearby.value >> r->n0 >> r->n1 >> r->s0 >> r->s1 >> r->k >>
        r->l >> r->shared_word_candidates;
    if (!numbers || !ParseIds(f[10], &r->candidates) || !ParseIds(f[11], &r->connected) ||
        !ParseIds(f[13], &r->loop_candidates) || !ParseIds(f[14], &r->loops)) {
      return false;
    }
    r->verification.clear();
    if (f[12] != "-") {
      std::istringstream list(f[12]);
      for (std::string item; std::getline(list, item, ',');) {
        int matches = 0, inliers = 0;
        if (std::sscanf(item.c_str(), "%d/%d", &matches, &inliers) != 2) return false;
        r->verification.push_back({matches, inliers});
      }
    }
    r->skipped = f[15] == "-" ? "" : f[15];
    return true;
  });
}

void WriteMergeLog(const std::string& path, const std::vector<MergeLogRecord>& records) {
  std::string text = "# event\tcurrent_map\tunconnected_submaps (stack, newest last)\tmerged_maps\n";
  for (const MergeLogRecord& r : records) {
    text += r.event + "\t" + r.current_map + "\t" + r.unconnected + "\t" + r.merged_maps + "\n";
  }
  WriteFileAtomically(path, text);
}

std::vector<MergeLogRecord> ReadMergeLog(const std::string& path) {
  return ReadLines<MergeLogRecord>(path, "merge log line", [](const std::string& line, MergeLogRecord* r) {
    const std::vector<std::string> f = SplitTabs(line);
    if (f.size() != 4) return false;
    *r = {f[0], f[1], f[2], f[3]};
    return true;
  });
}

bool JoinedByGnss(const SubmapEdgeRecord& edge) {
  return edge.status.rfind("joined by GNSS", 0) == 0;
}

std::map<int64_t, int64_t> ViewJoinedParts(const std::vector<SubmapEdgeRecord>& edges) {
  std::map<int64_t, int64_t> part;
  const std::function<int64_t(int64_t)> find = [&](int64_t id) {
    const int64_t up = part.try_emplace(id, id).first->second;
    return up == id ? id : part[id] = find(up);
  };
  for (const SubmapEdgeRecord& e : edges) {
    const int64_t a = find(e.a.value), b = find(e.b.value);
    if (e.status == "merged" && a != b) part[std::max(a, b)] = std::min(a, b);
  }
  for (auto& [id, up] : part) up = find(id);
  return part;
}

namespace {

const std::string kRefused = "refused: ";

bool Merged(const SubmapEdgeRecord& e) {
  return e.status == "merged";
}

// The reason an edge was refused, or "" for one that was not.
std::string RefusedReason(const SubmapEdgeRecord& e) {
  return e.status.rfind(kRefused, 0) == 0 ? e.status.substr(kRefused.size()) : std::string();
}

}  // namespace

void WriteSubmapGraphDot(const std::string& path, const std::vector<SubmapRecord>& submaps,
                         const std::vector<SubmapEdgeRecord>& edges) {
  std::ostringstream out;
  out << "graph submaps {\n  // edge weight -C; bold: Kruskal's spanning tree; blue: joined by GNSS, no view joins "
         "them\n";
  for (const SubmapRecord& s : submaps) {
    out << "  \"" << SubmapName(s.submap) << "\" [label=\"" << SubmapName(s.submap) << "\\n"
        << s.keyframes << " kf, map " << s.component << "\"];\n";
  }
  for (const SubmapEdgeRecord& e : edges) {
    const std::string refused = RefusedReason(e);
    char label[128];
    if (JoinedByGnss(e)) {
      std::snprintf(label, sizeof(label), "%s", e.status.c_str());
    } else {
      std::snprintf(
          label, sizeof(label), "C=%.1f (F=%d M=%d %.0f deg%s)", e.strength, e.connected_frames, e.map_points,
          e.median_angle_deg,
          e.disagreeing_frames > 0 ? (", " + std::to_string(e.disagreeing_frames) + " outvoted").c_str() : "");
    }
    out << "  \"" << SubmapName(e.a) << "\" -- \"" << SubmapName(e.b) << "\" [label=\"" << label
        << (refused.empty() ? "" : "\\nrefused: " + refused) << "\""
        << (Merged(e)         ? ", style=bold"
            : JoinedByGnss(e) ? ", style=bold, color=blue"
            : refused.empty() ? ", style=dashed"
                              : ", style=dotted, color=red")
        << "];\n";
  }
  out << "}\n";
  WriteFileAtomically(path, out.str());
}

void WriteSubmapGraphPng(const std::string& path, const std::vector<SubmapRecord>& submaps,
                         const std::vector<SubmapEdgeRecord>& edges) {
  // Submaps on a circle, edges with their strength.
  const int size = 640;
  cv::Mat image(size, size, CV_8UC3, cv::Scalar(255, 255, 255));
  std::map<SubmapId, cv::Point> at;
  const size_t n = submaps.size();
  for (size_t i = 0; i < n; ++i) {
    const double angle = 2 * M_PI * static_cast<double>(i) / static_cast<double>(n) - M_PI / 2;
    at[submaps[i].submap] = cv::Point(size / 2 + static_cast<int>(230 * std::cos(angle)),
                                      size / 2 + static_cast<int>(230 * std::sin(angle)));
  }
  for (const SubmapEdgeRecord& e : edges) {
    const bool in_tree = Merged(e), by_gnss = JoinedByGnss(e);
    cv::line(image, at[e.a], at[e.b],
             in_tree   ? cv::Scalar(40, 40, 200)
             : by_gnss ? cv::Scalar(200, 90, 30)
                       : cv::Scalar(180, 180, 180),
             in_tree || by_gnss ? 3 : 1, cv::LINE_AA);
    char label[32] = "GNSS";
    if (!by_gnss) std::snprintf(label, sizeof(label), "%.0f", e.strength);
    cv::putText(image, label, (at[e.a] + at[e.b]) / 2, cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(0, 0, 0), 1,
                cv::LINE_AA);
  }
  static const cv::Scalar kColours[] = {{200, 90, 30}, {40, 40, 220}, {40, 160, 40}, {180, 40, 180}, {20, 150, 220}};
  for (const SubmapRecord& s : submaps) {
    cv::circle(image, at[s.submap], 22, kColours[s.component % 5], cv::FILLED, cv::LINE_AA);
    cv::putText(image, SubmapName(s.submap), at[s.submap] + cv::Point(-16, 5), cv::FONT_HERSHEY_SIMPLEX, 0.45,
                cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
  }
  cv::putText(image,
              "submap graph: edges labelled C, spanning tree in red, GNSS junctions in blue, a colour per merged map",
              cv::Point(10, 20), cv::FONT_HERSHEY_SIMPLEX, 0.45, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  WritePng(path, image);
}

}  // namespace stitch
