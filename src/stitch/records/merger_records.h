#pragma once
// The merger's record files, written by the merger service (and `stitch map`) into its record
// folder, read by `stitch run` / `stitch eval` and by the tests:
//   submaps.tsv           each submap's merged map and Sim3 (SubmapRecord)
//   keyframes_merged.tsv  each merged keyframe's refined pose (MergedKeyframeRecord)
//   connections.tsv       each verified connected frame and in-map loop (ConnectionRecord)
//   edges.tsv             each pair of submaps with connected frames, and what became of it
//                         (SubmapEdgeRecord)
//   retrieval.tsv         each connected-frame query with the method's N0, N1, S0, S1, k, l
//                         (RetrievalRecord)
//   merge_log.tsv         the stack of unconnected submaps at each event (MergeLogRecord)
//   graph.dot, graph.png  the submap graph drawn from submaps.tsv's and edges.tsv's records
// Each file has one writer and one reader here; writers replace the file as one act
// (WriteFileAtomically). Readers throw stitch::Error naming the file and line.

#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "stitch/geometry/rigid3.h"
#include "stitch/util/ids.h"

namespace stitch {

struct SubmapRecord {
  SubmapId submap;
  int component = -1;  // merged map; 0 is the largest
  SubmapId root;       // the merged map's frame is this submap's
  size_t keyframes = 0, points = 0;
  bool closed = false;
  Sim3d world_from_submap;  // into the merged map's frame
};
void WriteSubmapRecords(const std::string& path, const std::vector<SubmapRecord>& records);
std::vector<SubmapRecord> ReadSubmapRecords(const std::string& path);

struct MergedKeyframeRecord {
  KeyframeId keyframe;
  int component = -1;
  Sim3d world_from_cam;  // refined by the pose graph; the scale is the keyframe's submap's
  int frame_index = -1;  // the keyframe's frame, and its image's time (-1 / 0 in files written
  int64_t t_ns = 0;      // before they were recorded)
};
void WriteMergedKeyframeRecords(const std::string& path, const std::vector<MergedKeyframeRecord>& records);
std::vector<MergedKeyframeRecord> ReadMergedKeyframeRecords(const std::string& path);

struct ConnectionRecord {
  KeyframeId keyframe_a, keyframe_b;
  int map_points = 0;
  double median_angle_deg = 0;
  Sim3d b_from_a;  // submap b's frame from a's
  // ConnectionGeometry (submap_graph.h): how it was verified and how well its points pin b_from_a.
  std::string verified_by = "descriptors";
  double bearing_spread_a = 0, bearing_spread_b = 0, line_ratio = 0, depth_disagreement = 0;
  // What the merger made of it: "used", or why not ("outvoted", "degenerate: ...", "loop").
  std::string verdict = "used";
};
void WriteConnectionRecords(const std::string& path, const std::vector<ConnectionRecord>& records);
std::vector<ConnectionRecord> ReadConnectionRecords(const std::string& path);

// An edge of the submap graph: the pair's connected frames summed up, and the verdict.
struct SubmapEdgeRecord {
  SubmapId a, b;
  double strength = 0;  // C
  int connected_frames = 0, map_points = 0, disagreeing_frames = 0;
  double median_angle_deg = 0;
  double agreement = 0;  // share of the pair's verified points that agree with its Sim3
  // "merged", "joined by GNSS (+-S m)" (no view joins them: their maps' GNSS placements do),
  // "agrees" (closes a cycle of merged submaps), "below min_connection_strength" or
  // "refused: <reason>".
  std::string status;
};
bool JoinedByGnss(const SubmapEdgeRecord& edge);
// The parts that views join (edges "merged") of each submap named in `edges`, each part named by
// its smallest submap id: with GNSS junctions, a merged map's parts.
std::map<int64_t, int64_t> ViewJoinedParts(const std::vector<SubmapEdgeRecord>& edges);
void WriteSubmapEdgeRecords(const std::string& path, const std::vector<SubmapEdgeRecord>& records);
std::vector<SubmapEdgeRecord> ReadSubmapEdgeRecords(const std::string& path);

// One connected-frame query, as the method's thresholds need to be studied.
struct RetrievalRecord {
  KeyframeId keyframe, previous, nearby;
  int n0 = 0, n1 = 0;                  // words shared with the previous / the ~50%-overlap keyframe
  double s0 = 0, s1 = 0;               // BoW scores with them
  double k = 0, l = 0;                 // N1/N0 and S1/S0
  int shared_word_candidates = 0;      // frames in other submaps passing k
  std::vector<KeyframeId> candidates;  // ...then passing l (verified in this order, at most max_candidates)
  std::vector<KeyframeId> connected;   // verified
  // Per candidate, then per loop candidate: descriptor matches, Sim3 inliers (0 if not tried).
  std::vector<std::pair<int, int>> verification;
  std::vector<KeyframeId> loop_candidates;  // in the same submap, outside the covisible window
  std::vector<KeyframeId> loops;            // verified
  std::string skipped;                      // why there was no query (first keyframe, no other submap...)
};
void WriteRetrievalRecords(const std::string& path, const std::vector<RetrievalRecord>& records);
std::vector<RetrievalRecord> ReadRetrievalRecords(const std::string& path);

// The merging process as the method's table shows it: at each event, the current map, the
// stack of unconnected submaps (newest last) and the merged maps (each "a+b+c").
struct MergeLogRecord {
  std::string event;
  std::string current_map;
  std::string unconnected;  // submap names separated by spaces; "" when none
  std::string merged_maps;  // merged maps separated by spaces
};
void WriteMergeLog(const std::string& path, const std::vector<MergeLogRecord>& records);
std::vector<MergeLogRecord> ReadMergeLog(const std::string& path);

// The submap graph for Graphviz (graph.dot) and as a picture (graph.png): each submap with its
// keyframes and merged map, each edge with its strength C; the spanning tree's edges ("merged")
// bold, refused ones dotted red with their reason.
void WriteSubmapGraphDot(const std::string& path, const std::vector<SubmapRecord>& submaps,
                         const std::vector<SubmapEdgeRecord>& edges);
void WriteSubmapGraphPng(const std::string& path, const std::vector<SubmapRecord>& submaps,
                         const std::vector<SubmapEdgeRecord>& edges);

}  // namespace stitch
