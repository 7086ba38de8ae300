#include "stitch/merging/merge_session.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <utility>

#include "stitch/io/colmap_model.h"
#include "stitch/io/output_frames.h"
#include "stitch/io/ply.h"
#include "stitch/io/trajectory.h"
#include "stitch/map/map_export.h"
#include "stitch/map/map_file.h"
#include "stitch/mosaic/geotiff.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "stitch/util/time.h"

namespace stitch {

namespace {
// Frames of the pose stream kept per aircraft: 9 hours at 30 fps.
constexpr size_t kMaxFramePoses = 1'000'000;
// Fixes kept in all: 10 hours at 10 Hz.
constexpr size_t kMaxGnssFixes = 360'000;
// Merges rolled back by the check after placement in one refinement, at most (each round solves
// and adjusts the largest map again).
constexpr int kMaxRollbacksPerRefinement = 3;

// COLMAP's image names: agentA-frameNNNNNN (`stitch export colmap` names them by the image files).
std::string ColmapImageName(const Keyframe& keyframe) {
  char name[48];
  std::snprintf(name, sizeof(name), "agent%d-frame%06d", AgentNumber(SubmapOf(keyframe.id)), keyframe.frame_index);
  return name;
}

}  // namespace

MergeSession::MergeSession(const MergerOptions& options, const Vocabulary* vocabulary, const ScalePyramid& pyramid,
                           std::string record_dir, std::vector<std::string> agents)
    : pyramid_(pyramid),
      merger_(options, vocabulary, pyramid_),
      record_dir_(std::move(record_dir)),
      agents_(std::move(agents)) {
  if (!options.prior_map.empty()) LoadPriorMap(options.prior_map);
}

void MergeSession::LoadPriorMap(const std::string& path) {
  const Stopwatch clock;
  SavedMap saved = ReadMapFile(path, MakeSubmapId(kSavedMapAgent, 0));
  if (saved.cameras.size() != 1) {
    throw Error(path + ": a map of " + std::to_string(saved.cameras.size()) +
                " cameras; maps of one camera only can be flown in again for now");
  }
  std::vector<KeyframeId> keyframes;
  for (const auto& [id, keyframe] : saved.map.keyframes()) keyframes.push_back(id);
  std::sort(keyframes.begin(), keyframes.end());
  const SubmapUpdate update =
      MakeResendSubmapUpdate(&saved.map, saved.cameras[0], keyframes, /*full_state=*/true, /*closed=*/true, 1);
  const double read_s = clock.ElapsedSeconds();
  // Named so no aircraft can be (agent names are channel prefixes, without spaces): no fixes or
  // pictures of an aircraft are taken for it.
  Apply(update, "saved map", /*first_part=*/true);
  FirstWholeFinalState(update.submap);
  prior_map_description_ = saved.description;
  STITCH_LOG(INFO) << "the saved map " << path << ": " << saved.map.num_keyframes() << " keyframes, "
                   << saved.map.num_points() << " points, read in " << read_s << " s, indexed in "
                   << clock.ElapsedSeconds() - read_s << " s (" << saved.description << ")";
}

MergeSession::Applied MergeSession::Apply(const SubmapUpdate& update, const std::string& agent, bool first_part) {
  Applied applied;
  // Two aircraft with the same agent number would mix their submaps: keep the first's.
  const auto [known, fresh] = agent_of_.try_emplace(update.submap, agent);
  if (!fresh && known->second != agent) {
    applied.refused = "that submap is " + known->second + "'s (two aircraft with one agent_number?)";
    return applied;
  }
  applied.accepted = true;
  applied.missing = merger_.Apply(update);
  ++applied_;
  cloud_stale_ = true;  // its points and keyframes, for the live view
  applied.newly_closed = update.closed && !closed_seen_[update.submap];
  closed_seen_[update.submap] = update.closed;
  if (merger_.connections().size() != connections_seen_ || applied.newly_closed || first_part) {
    connections_seen_ = merger_.connections().size();
    OnGraphChange(applied.newly_closed ? "submap " + SubmapName(update.submap) + " closed"
                                       : "keyframe of submap " + SubmapName(update.submap));
  }
  return applied;
}

std::optional<MergedMap> MergeSession::MergeLargestMap(Merger::Graph* graph, const SubmapFixes& fixes) const {
  SubmapId root;
  int members = 0;
  for (const auto& [id, placement] : graph->placement) {
    if (placement.component != 0) continue;
    root = placement.root;
    ++members;
  }
  int loops = 0;  // confirmed loops within component 0
  for (const ConnectedFrame& c : graph->agreeing) {
    loops +=
        SubmapOf(c.keyframe_a) == SubmapOf(c.keyframe_b) && graph->placement.at(SubmapOf(c.keyframe_a)).component == 0;
  }
  // A map of one submap is adjusted as a whole too: the mapper's local adjustments never move
  // its keyframes all together (the calm survey: ATE 0.153 -> 0.130 m, docs/benchmarks.md).
  if (members == 0) return std::nullopt;
  const SubmapReplica& replica = merger_.submaps().at(root);
  if (!replica.camera) return std::nullopt;
  const Stopwatch clock;
  const auto placed = graph->on_earth.find(0);
  const FixesOnEarth on_earth{placed != graph->on_earth.end() ? placed->second.enu_from_world : Sim3d(), &fixes,
                              &merger_.options().georeference};
  MergedMap merged = AssembleMergedMap(merger_.submaps(), graph->placement, graph->keyframe_poses, graph->agreeing, 0,
                                       pyramid_, replica.camera->Intrinsics(), merger_.options().merged_map,
                                       placed != graph->on_earth.end() ? &on_earth : nullptr);
  for (const auto& [id, pose] : merged.keyframe_poses) graph->keyframe_poses[id] = pose;
  const BundleAdjustmentReport& ba = merged.bundle_adjustment;
  STITCH_LOG(INFO) << "merged map of " << members << " submaps with " << loops
                   << " loops: " << merged.map.num_keyframes() << " keyframes, " << merged.map.num_points()
                   << " points; fused " << merged.points_fused_by_connection << " points from connected frames and "
                   << merged.points_fused_by_projection << " by projection; bundle adjustment " << ba.initial_rms_px
                   << " -> " << ba.final_rms_px << " px rms (" << ba.observations << " observations, "
                   << ba.outliers_removed << " outliers removed) in " << clock.ElapsedMs() << " ms";
  if (ba.priors.used + ba.priors.set_aside > 0) {
    char rms[80];
    std::snprintf(rms, sizeof(rms), "%.2f -> %.2f", ba.priors.initial_rms, ba.priors.final_rms);
    STITCH_LOG(INFO) << "GNSS in the bundle adjustment: " << ba.priors.used << " fixes hold the keyframes, "
                     << ba.priors.set_aside << " set aside as outliers; their residuals " << rms
                     << " of their stated sigmas (rms)";
  }
  for (const auto& [pair, junction] : merged.junctions) {
    STITCH_LOG(INFO) << "junction " << SubmapName(pair.first) << "-" << SubmapName(pair.second) << ": " << junction.kept
                     << " of " << junction.joined << " joining observations kept";
  }
  return merged;
}

void MergeSession::Refine(const std::string& why) {
  const Stopwatch clock;
  const Merger::Reverification again = merger_.ReverifyStaleConnections();
  if (again.reverified > 0) {
    STITCH_LOG(INFO) << "verified " << again.reverified
                     << " connected frames again on their submaps' newer points: " << again.changed << " moved, "
                     << again.stale << " could not be (kept as stale: they count where the fresh ones agree)";
    OnGraphChange("connected frames verified again (" + why + ")");
  }
  const SubmapFixes fixes = FixesOfSubmaps();
  Refined refined{merger_.Solve(/*refine=*/true, fixes), std::nullopt};
  refined.merged = MergeLargestMap(&refined.graph, fixes);
  // Checked after placement: a merge whose junction the adjustment could not hold is rolled back
  // (its edge refused until more connected frames arrive) and the maps are solved again.
  const bool check = merger_.options().merged_map.fuse_points;  // junctions are made by fusing
  for (int round = 0; check && refined.merged && round < kMaxRollbacksPerRefinement; ++round) {
    const std::vector<DoubtedEdge> doubted =
        CheckJunctions(*refined.merged, refined.graph.tree, merger_.options().acceptance);
    if (doubted.empty()) break;
    for (const DoubtedEdge& d : doubted) {
      STITCH_LOG(WARNING) << "merge of submaps " << SubmapName(d.edge.a) << " and " << SubmapName(d.edge.b)
                          << " rolled back: " << d.reason;
      merger_.RefuseAfterPlacement(d.edge, d.reason);
    }
    OnGraphChange("merge rolled back after placement (" + why + ")");
    refined = Refined{merger_.Solve(/*refine=*/true, fixes), std::nullopt};
    refined.merged = MergeLargestMap(&refined.graph, fixes);
  }
  Show(refined.graph);
  refined_ = std::move(refined);
  refined_at_ = applied_;
  if (!record_dir_.empty()) {
    // The last good map on disk at every refinement, not only at the end.
    try {
      WriteRecords(refined_->graph, refined_->merged ? &*refined_->merged : nullptr);
    } catch (const std::exception& e) {
      STITCH_LOG(ERROR) << "writing the merger's records failed: " << e.what();
    }
    WriteLiveTrajectory();
  }
  STITCH_LOG(INFO) << "refined the merged maps (" << why << ") in " << clock.ElapsedMs() << " ms";
}

bool MergeSession::Finish() {
  const bool refine_now = !refined_ || refined_at_ != applied_;
  if (refine_now) Refine("the run ended");  // writes the records
  for (const auto& [id, replica] : merger_.submaps()) {
    const SubmapCompleteness c = CompletenessOf(replica);
    if (c.missing == 0 && replica.closed) continue;
    STITCH_LOG(WARNING) << "submap " << SubmapName(id) << " is incomplete on the ground: " << c.missing << " of its "
                        << c.listed << " keyframes" << (replica.closed ? "" : " and its final state")
                        << " never arrived; the map holds what did";
  }
  const Merger::Graph& graph = refined_->graph;
  const MergedMap* merged = refined_->merged ? &*refined_->merged : nullptr;
  if (!record_dir_.empty()) {
    try {
      if (!refine_now) WriteRecords(graph, merged);
      // The COLMAP model, a product for after the flight, only at the end.
      WriteColmapRecord(graph, merged);
      if (merger_.options().save_map) WriteSavedMap(graph, merged);
    } catch (const std::exception& e) {
      STITCH_LOG(ERROR) << "writing the merger's records failed: " << e.what();
    }
  }
  WriteLiveTrajectory();
  if (merger_.options().mosaic.live) {
    // The pictures that came last, on the refined map, and the file.
    mosaic_updated_at_ = 0;
    UpdateMosaicIfDue();
    if (mosaic_unwritten_) WriteLiveMosaic();
    STITCH_LOG(INFO) << "live mosaic: " << mosaic_cost_.laid << " pictures laid, " << mosaic_cost_.moved
                     << " moved, drawn whole " << mosaic_cost_.redrawn << " times, in " << mosaic_cost_.updates
                     << " updates: " << mosaic_cost_.update_ms << " ms CPU; mosaic_live.tif written "
                     << mosaic_cost_.writes << " times, " << mosaic_cost_.write_ms << " ms CPU";
  }
  return refine_now;
}

void MergeSession::OnGraphChange(const std::string& event) {
  const Merger::Graph graph = merger_.Solve(/*refine=*/false, FixesOfSubmaps());
  // The current map: the merged map holding the newest submap; the stack: every other submap.
  SubmapId newest;
  for (const auto& [id, replica] : merger_.submaps()) {
    if (!newest.valid() || newest < id) newest = id;
  }
  if (!newest.valid()) return;
  const int current = graph.placement.at(newest).component;
  std::string current_map, stack;
  // Merged maps listed by their oldest submap (component numbers follow sizes and may change).
  std::map<int, SubmapId> oldest;
  for (const auto& [id, placement] : graph.placement) {
    if (!oldest.count(placement.component)) oldest[placement.component] = id;  // placement is ordered by id
  }
  std::map<SubmapId, std::string> merged;
  for (const auto& [id, placement] : graph.placement) {
    std::string& into = placement.component == current ? current_map : stack;
    into += (into.empty() ? "" : " ") + SubmapName(id);
    std::string& names = merged[oldest[placement.component]];
    names += (names.empty() ? "" : "+") + SubmapName(id);
  }
  std::string maps;
  for (const auto& [first, names] : merged) maps += (maps.empty() ? "" : " ") + names;
  // Edges refused by the acceptance checks, each said once (and again when its reason changes).
  std::map<std::pair<SubmapId, SubmapId>, std::string> refused;
  for (const SubmapEdge& e : graph.edges) {
    if (e.refused.empty()) continue;
    refused[{e.a, e.b}] = e.refused;
    const auto before = refused_edges_.find({e.a, e.b});
    if (before != refused_edges_.end() && before->second == e.refused) continue;
    const std::string what = "edge " + SubmapName(e.a) + "-" + SubmapName(e.b) + " refused: " + e.refused;
    STITCH_LOG(WARNING) << what;
    merge_log_.push_back({what, current_map, stack, maps});
  }
  refused_edges_.swap(refused);
  // GNSS junctions, each said when made and when undone.
  std::map<std::pair<SubmapId, SubmapId>, double> junctions;
  for (const SubmapEdge& e : graph.tree) {
    if (e.kind == EdgeKind::kGnss) junctions[{e.a, e.b}] = e.gnss_sigma_m;
  }
  const auto say = [&](const std::string& what) {
    STITCH_LOG(INFO) << what;
    merge_log_.push_back({what, current_map, stack, maps});
  };
  for (const auto& [pair, sigma] : junctions) {
    if (gnss_junctions_.count(pair)) continue;
    char what[160];
    std::snprintf(what, sizeof(what),
                  "submaps %s and %s joined where GNSS places their maps (+-%.2f m): no view joins them",
                  SubmapName(pair.first).c_str(), SubmapName(pair.second).c_str(), sigma);
    say(what);
  }
  for (const auto& [pair, sigma] : gnss_junctions_) {
    if (junctions.count(pair)) continue;
    const bool together = graph.placement.at(pair.first).component == graph.placement.at(pair.second).component;
    say("GNSS junction " + SubmapName(pair.first) + "-" + SubmapName(pair.second) + " undone: " +
        (together ? "views or another junction join the two now" : "GNSS no longer places both their maps"));
  }
  gnss_junctions_.swap(junctions);
  for (const auto& [root, why] : graph.not_joined_by_gnss) {
    const auto before = not_joined_by_gnss_.find(root);
    if (before != not_joined_by_gnss_.end() && before->second == why) continue;
    const std::string what = "the map of submap " + SubmapName(root) + " is not joined by GNSS: " + why;
    STITCH_LOG(WARNING) << what;
    merge_log_.push_back({what, current_map, stack, maps});
  }
  not_joined_by_gnss_ = graph.not_joined_by_gnss;
  const std::string row = current_map + "\t" + stack + "\t" + maps;
  if (row == last_stack_) return;
  last_stack_ = row;
  merge_log_.push_back({event, current_map, stack, maps});
  STITCH_LOG(INFO) << event << ": current map " << current_map << "; unconnected " << (stack.empty() ? "-" : stack);
  Show(graph);
}

void MergeSession::Show(const Merger::Graph& graph) {
  latest_placement_ = graph.placement;
  latest_on_earth_ = graph.on_earth;
  trajectory_stale_ = true;
  cloud_stale_ = true;
  if (on_graph_) on_graph_(graph);
}

bool MergeSession::AddFramePose(const std::string& agent, const TrackedFramePose& pose, std::string* why) {
  const SubmapId submap(pose.submap_id);
  if (pose.frame_index < 0 || pose.t_ns < 0) {
    *why = "negative frame index or time";
    return false;
  }
  if (!submap.valid() || SubmapOf(submap) != submap) {
    *why = "names no submap (" + std::to_string(pose.submap_id) + ")";
    return false;
  }
  if (pose.reference_keyframe != -1 &&
      (pose.reference_keyframe < 0 || SubmapOf(KeyframeId(pose.reference_keyframe)) != submap)) {
    *why = "its reference keyframe is not of its submap";
    return false;
  }
  std::lock_guard<std::mutex> lock(poses_mutex_);
  if (poses_pending_.size() >= kMaxFramePoses) {
    *why = "the worker is " + std::to_string(kMaxFramePoses) + " poses behind";
    return false;
  }
  poses_pending_.emplace_back(agent, pose);
  ++poses_received_;
  return true;
}

std::optional<GeodeticPoint> MergeSession::gnss_origin() const {
  std::lock_guard<std::mutex> lock(gnss_mutex_);
  if (!gnss_plane_) return std::nullopt;
  return gnss_plane_->origin();
}

bool MergeSession::AddGnssFix(const std::string& agent, const GnssFix& fix, std::string* why) {
  if (const std::string wrong = WhyNotAFix(fix); !wrong.empty()) {
    *why = wrong;
    return false;
  }
  std::lock_guard<std::mutex> lock(gnss_mutex_);
  std::map<int64_t, HeldFix>& fixes = gnss_[agent];
  if (!fixes.count(fix.t_ns)) {
    size_t held = 0;
    for (const auto& item : gnss_) held += item.second.size();
    if (held >= kMaxGnssFixes) {
      *why = "the merger holds " + std::to_string(kMaxGnssFixes) + " fixes already";
      return false;
    }
  }
  HeldFix& held = fixes[fix.t_ns];
  held.fix = fix;
  held.enu.reset();
  if (fix.usable()) {
    if (!gnss_plane_) gnss_plane_.emplace(fix.position);
    held.enu = ToEnu({fix}, *gnss_plane_).front();
  }
  return true;
}

SubmapFixes MergeSession::FixesOfSubmaps() const {
  const GeoReferenceOptions& geo = merger_.options().georeference;
  if (!geo.enabled || !merger_.options().join_by_gnss) return {};
  const auto margin_ns = static_cast<int64_t>((geo.max_interpolation_gap_s + std::abs(geo.time_offset_s)) * 1e9);
  SubmapFixes by_submap;
  std::lock_guard<std::mutex> lock(gnss_mutex_);
  for (const auto& [id, replica] : merger_.submaps()) {
    const auto agent = agent_of_.find(id);
    if (agent == agent_of_.end() || replica.map.num_keyframes() == 0) continue;
    const auto fixes = gnss_.find(agent->second);
    if (fixes == gnss_.end()) continue;
    int64_t first = std::numeric_limits<int64_t>::max(), last = std::numeric_limits<int64_t>::min();
    for (const auto& [keyframe_id, keyframe] : replica.map.keyframes()) {
      first = std::min(first, keyframe.t_ns);
      last = std::max(last, keyframe.t_ns);
    }
    constexpr int64_t kMin = std::numeric_limits<int64_t>::min(), kMax = std::numeric_limits<int64_t>::max();
    const int64_t from = first > kMin + margin_ns ? first - margin_ns : kMin;
    const int64_t to = last < kMax - margin_ns ? last + margin_ns : kMax;
    std::vector<EnuFix>& own = by_submap[id];
    for (auto f = fixes->second.lower_bound(from); f != fixes->second.end() && f->first <= to; ++f) {
      if (f->second.enu) own.push_back(*f->second.enu);
    }
  }
  return by_submap;
}

int64_t MergeSession::frame_poses_received() const {
  std::lock_guard<std::mutex> lock(poses_mutex_);
  return poses_received_;
}

void MergeSession::WriteLiveTrajectoryIfDue() {
  const double interval = merger_.options().live_outputs_interval_s;
  if (interval > 0 && MonotonicSeconds() - trajectory_written_at_ >= interval) WriteLiveTrajectory();
}

void MergeSession::TakePendingPoses() {
  std::vector<std::pair<std::string, TrackedFramePose>> pending;
  {
    std::lock_guard<std::mutex> lock(poses_mutex_);
    pending.swap(poses_pending_);
  }
  for (auto& [agent, pose] : pending) {
    std::map<int, TrackedFramePose>& frames = frame_poses_[agent];
    if (frames.size() >= kMaxFramePoses && !frames.count(pose.frame_index)) continue;
    frames[pose.frame_index] = pose;
    trajectory_stale_ = true;
  }
}

bool MergeSession::AddKeyframePicture(const KeyframePicture& picture, std::string* why) {
  if (!merger_.options().mosaic.live) return true;
  if (picture.width < 2 || picture.height < 2 || picture.jpeg.empty() || picture.frame_index < 0 || picture.agent < 0 ||
      picture.agent > 200) {
    *why = "a keyframe picture without a size, bytes, a frame or an aircraft";
    return false;
  }
  constexpr size_t kMaxPicturesWaiting = 10000;
  std::lock_guard<std::mutex> lock(poses_mutex_);
  if (pictures_pending_.size() >= kMaxPicturesWaiting) {
    *why = "10000 pictures wait for the live mosaic already";
    return false;
  }
  pictures_pending_.push_back(picture);
  return true;
}

LiveMosaic::MapState MergeSession::MapsForMosaic(const std::map<int, std::pair<std::string, int>>& pictured) const {
  LiveMosaic::MapState state;
  // The maps drawn, each into the mosaic's map frame: the largest alone in its own frame, or
  // where the fixes place it, every map they place in their ENU frame.
  std::map<int, Sim3d> drawn;
  if (const auto largest = latest_on_earth_.find(0); largest != latest_on_earth_.end()) {
    state.on_earth = true;
    state.frame = LiveMosaic::kFrameOnEarth;
    for (const auto& [component, on_earth] : latest_on_earth_) drawn[component] = on_earth.enu_from_world;
  } else {
    drawn[0] = Sim3d();
  }
  std::map<int64_t, KeyframeInSubmap> keyframes;
  std::map<int64_t, SubmapInMap> placement;
  for (const auto& [id, p] : latest_placement_) {
    placement[id.value] = {p.component, p.world_from_submap};
    if (p.component == 0 && !state.on_earth) state.frame = p.root.value;
  }
  // The maps' points (at most 20,000, evenly taken) through their submaps' placements.
  size_t total = 0;
  for (const auto& [id, replica] : merger_.submaps()) {
    const auto p = latest_placement_.find(id);
    if (p != latest_placement_.end() && drawn.count(p->second.component)) total += replica.map.points().size();
  }
  const size_t stride = std::max<size_t>(1, total / 20000);
  size_t n = 0;
  for (const auto& [id, replica] : merger_.submaps()) {
    for (const auto& [keyframe_id, keyframe] : replica.map.keyframes()) {
      keyframes[keyframe_id.value] = {keyframe.cam_from_world, keyframe.frame_index};
    }
    const auto p = latest_placement_.find(id);
    if (p == latest_placement_.end()) continue;
    const auto to_mosaic = drawn.find(p->second.component);
    if (to_mosaic == drawn.end()) continue;
    const Sim3d mosaic_from_submap = to_mosaic->second * p->second.world_from_submap;
    for (const auto& [point_id, point] : replica.map.points()) {
      if (n++ % stride == 0) state.points.push_back(mosaic_from_submap * point.position);
    }
  }
  // The pictured frames the pose stream has, placed as the live trajectory places them.
  std::map<std::string, std::vector<TrackedFramePose>> frames;
  std::map<std::pair<std::string, int>, int> key_of;
  for (const auto& [key, at] : pictured) {
    const auto agent = frame_poses_.find(at.first);
    if (agent == frame_poses_.end()) continue;
    const auto pose = agent->second.find(at.second);
    if (pose == agent->second.end()) continue;
    frames[at.first].push_back(pose->second);
    key_of[at] = key;
  }
  for (const auto& [agent, list] : frames) {
    for (const PoseRecord& p : PlaceTrackedFrames(list, keyframes, placement, {})) {
      const auto to_mosaic = drawn.find(p.component);
      if (to_mosaic == drawn.end()) continue;
      // A camera's pose in a frame of other units: its centre carried, its axes turned (the scale
      // changes its picture's depths, not where it looks).
      const Sim3d& s = to_mosaic->second;
      state.world_from_cam[key_of.at({agent, p.frame_index})] =
          Rigid3d(s.rotation * p.world_from_cam.rotation, s * p.world_from_cam.translation);
    }
  }
  return state;
}

void MergeSession::UpdateMosaicIfDue() {
  if (mosaic_failed_) return;
  try {
    UpdateMosaic();
  } catch (const std::exception& e) {
    // The mosaic is a picture of the flight: its failure must cost the flight nothing.
    mosaic_failed_ = true;
    STITCH_LOG(ERROR) << "the live mosaic stopped: " << e.what();
  }
}

void MergeSession::UpdateMosaic() {
  const MosaicOptions& options = merger_.options().mosaic;
  const double interval = options.interval_s;
  if (!options.live || MonotonicSeconds() - mosaic_updated_at_ < interval) return;
  mosaic_updated_at_ = MonotonicSeconds();
  std::vector<KeyframePicture> pictures;
  {
    std::lock_guard<std::mutex> lock(poses_mutex_);
    pictures.swap(pictures_pending_);
  }
  if (!live_mosaic_) live_mosaic_.emplace(options);
  std::vector<KeyframePicture> waiting;  // of a submap the merger does not hold yet
  for (KeyframePicture& picture : pictures) {
    const auto replica = merger_.submaps().find(SubmapId(picture.submap_id));
    if (replica == merger_.submaps().end() || !replica->second.camera) {
      waiting.push_back(std::move(picture));
      continue;
    }
    // Its JPEG header's size was checked against what it claims (the picture's width and height).
    if (replica->second.camera->width() < picture.width || replica->second.camera->height() < picture.height) continue;
    const int key = picture.agent * 10'000'000 + picture.frame_index % 10'000'000;
    const std::string agent = agent_of_.count(replica->first) ? agent_of_.at(replica->first) : std::string();
    pictured_[key] = {agent, picture.frame_index};
    newest_picture_utime_ = std::max(newest_picture_utime_, picture.sent_utime);
    live_mosaic_->AddPicture(key, replica->second.camera->Resized(picture.width, picture.height),
                             std::move(picture.jpeg));
  }
  if (!waiting.empty()) {
    std::lock_guard<std::mutex> lock(poses_mutex_);
    pictures_pending_.insert(pictures_pending_.begin(), std::make_move_iterator(waiting.begin()),
                             std::make_move_iterator(waiting.end()));
  }
  if (pictured_.empty() || latest_placement_.empty()) return;
  TakePendingPoses();
  const double started = ThreadCpuMs();
  const LiveMosaic::Change change = live_mosaic_->Update(MapsForMosaic(pictured_));
  // Said once per kind of wait (the text to its colon), not once per update.
  if (const std::string& waits = live_mosaic_->waiting_for();
      waits.substr(0, waits.find(':')) != mosaic_waits_for_.substr(0, mosaic_waits_for_.find(':'))) {
    if (!waits.empty()) {
      STITCH_LOG(INFO) << "the live mosaic waits for " << waits;
    }
    mosaic_waits_for_ = waits;
  }
  if (change.withdrawn) {
    STITCH_LOG(INFO) << "the live mosaic drawn so far is withdrawn: it waits for " << live_mosaic_->waiting_for();
    mosaic_unwritten_ = false;
    if (!record_dir_.empty()) {
      std::error_code ignored;  // none written yet
      std::filesystem::remove(std::filesystem::path(record_dir_) / "mosaic_live.tif", ignored);
    }
  }
  ++mosaic_cost_.updates;
  mosaic_cost_.update_ms += ThreadCpuMs() - started;
  mosaic_cost_.laid += change.laid;
  mosaic_cost_.moved += change.moved;
  mosaic_cost_.redrawn += change.redrawn;
  if (change.tiles > 0 || change.redrawn) {  // laid, moved, or taken out
    mosaic_unwritten_ = true;
    STITCH_LOG(DEBUG) << "live mosaic: " << change.laid << " pictures laid, " << change.moved << " moved, "
                      << change.tiles << " tiles" << (change.redrawn ? ", drawn again whole" : "") << " in "
                      << change.cpu_ms << " ms";
  }
  // How long a picture took to its tile: the newest one taken since pictures were last laid.
  const int64_t laid_picture_utime = change.laid > 0 ? std::exchange(newest_picture_utime_, 0) : 0;
  // Every tile drawn anew goes to the viewer: those of pictures laid or moved, and those a picture
  // leaving the map emptied.
  if (options.publish_tiles) {
    const double encoding = ThreadCpuMs();
    std::vector<LiveMosaicTile> tiles = live_mosaic_->TakeChangedTiles();
    mosaic_cost_.update_ms += ThreadCpuMs() - encoding;
    if (!mosaic_tiles_.tiles.empty() && !tiles.empty() &&
        tiles.front().revision != mosaic_tiles_.tiles.front().revision) {
      mosaic_tiles_.tiles.clear();  // the viewer drops the older revision's anyway
    }
    mosaic_tiles_.tiles.insert(mosaic_tiles_.tiles.end(), std::make_move_iterator(tiles.begin()),
                               std::make_move_iterator(tiles.end()));
    mosaic_tiles_.newest_picture_utime = std::max(mosaic_tiles_.newest_picture_utime, laid_picture_utime);
  }
  // The file at most a tenth of the merger's time: a large mosaic takes a while to compress.
  const double file_interval = std::max(merger_.options().live_outputs_interval_s, 10 * mosaic_write_cost_s_);
  if (mosaic_unwritten_ && MonotonicSeconds() - mosaic_written_at_ >= file_interval) {
    WriteLiveMosaic();
  }
  // Per picture laid (again, when the whole mosaic is drawn anew): moves ride along, as the
  // updates' fixed costs do, and are judged only once 8 were laid.
  const int laid = mosaic_cost_.laid;
  if (const double limit = options.live_max_cpu_ms_per_picture;
      limit > 0 && laid >= 8 && mosaic_cost_.update_ms > limit * laid) {
    // What it drew stays: its tiles went to the viewer, its file is written at the end.
    mosaic_failed_ = true;
    STITCH_LOG(WARNING)
        << "the live mosaic stopped with " << live_mosaic_->laid() << " pictures drawn: "
        << mosaic_cost_.update_ms / laid << " ms CPU per picture laid, over mosaic.live_max_cpu_ms_per_picture (" << limit
        << "): a map that is not a survey of the ground? (stitch mosaic RUN makes one from the records)";
  }
}

MergeSession::MosaicTiles MergeSession::TakeMosaicTiles() {
  MosaicTiles taken;
  std::swap(taken, mosaic_tiles_);
  return taken;
}

void MergeSession::WriteLiveMosaic() {
  if (record_dir_.empty() || !live_mosaic_ || !live_mosaic_->mosaic()) return;
  const double started = ThreadCpuMs();  // the merger's own time, whatever else the machine runs
  mosaic_written_at_ = MonotonicSeconds();
  mosaic_unwritten_ = false;
  try {
    const MosaicRaster raster = live_mosaic_->mosaic()->Render();
    if (raster.colour.empty()) return;
    GeoTiffImage tiff;
    tiff.colour = raster.colour;
    tiff.coverage = raster.coverage;
    const MosaicGrid& grid = live_mosaic_->mosaic()->grid();
    tiff.pixel_size = grid.gsd;
    tiff.west = grid.origin.x() + raster.col0 * grid.gsd;
    tiff.north = grid.origin.y() - raster.row0 * grid.gsd;
    tiff.deflate_level = 1;  // written again and again during the flight
    tiff.metadata["TIFFTAG_SOFTWARE"] = "stitch";
    const std::optional<GeodeticPoint> origin = gnss_origin();
    if (live_mosaic_->frame() == LiveMosaic::kFrameOnEarth && origin) {
      // The fixes' ENU frame: east and north of its origin are the ellipsoidal orthographic
      // projection's there (PROJ's), a CRS any GIS reads.
      char crs[200];
      std::snprintf(crs, sizeof(crs), "+proj=ortho +lat_0=%.9f +lon_0=%.9f +ellps=WGS84 +units=m +no_defs",
                    origin->latitude_deg, origin->longitude_deg);
      tiff.crs = crs;
      tiff.metadata["STITCH_FRAME"] = "the maps the GNSS fixes place, east and north of the first fix, metres";
    } else {
      tiff.metadata["STITCH_FRAME"] = "the largest merged map's frame, levelled on its points, in its units";
    }
    tiff.metadata["STITCH_PICTURES"] = std::to_string(live_mosaic_->laid());
    WriteGeoTiff((std::filesystem::path(record_dir_) / "mosaic_live.tif").string(), tiff);
  } catch (const std::exception& e) {
    STITCH_LOG(ERROR) << "writing mosaic_live.tif failed: " << e.what();
  }
  const double cost_ms = ThreadCpuMs() - started;
  mosaic_write_cost_s_ = cost_ms * 1e-3;
  ++mosaic_cost_.writes;
  mosaic_cost_.write_ms += cost_ms;
}

void MergeSession::WriteLiveTrajectory() {
  trajectory_written_at_ = MonotonicSeconds();
  TakePendingPoses();
  if (!trajectory_stale_ || record_dir_.empty() || latest_placement_.empty()) return;
  trajectory_stale_ = false;
  // Keyframes as the ground holds them now, the newest placement, and the last refinement's
  // keyframe poses where their merged map's frame (its root) is still the same.
  std::map<int64_t, KeyframeInSubmap> keyframes;
  for (const auto& [id, replica] : merger_.submaps()) {
    for (const auto& [keyframe_id, keyframe] : replica.map.keyframes()) {
      keyframes[keyframe_id.value] = {keyframe.cam_from_world, keyframe.frame_index};
    }
  }
  std::map<int64_t, SubmapInMap> placement;
  for (const auto& [id, p] : latest_placement_) placement[id.value] = {p.component, p.world_from_submap};
  std::map<int64_t, Sim3d> refined;
  if (refined_) {
    for (const auto& [id, pose] : refined_->graph.keyframe_poses) {
      const auto then = refined_->graph.placement.find(SubmapOf(id));
      const auto now = latest_placement_.find(SubmapOf(id));
      if (then != refined_->graph.placement.end() && now != latest_placement_.end() &&
          then->second.root == now->second.root) {
        refined[id.value] = pose;
      }
    }
  }
  const std::filesystem::path dir(record_dir_);
  for (const auto& [agent, frames] : frame_poses_) {
    std::vector<TrackedFramePose> list;
    list.reserve(frames.size());
    for (const auto& [index, pose] : frames) list.push_back(pose);
    Trajectory trajectory;
    for (const PoseRecord& p : PlaceTrackedFrames(list, keyframes, placement, refined)) {
      if (p.component == 0) trajectory.Add({p.t_ns, p.world_from_cam});
    }
    const std::string name = agents_.size() <= 1 ? "trajectory.tum" : "trajectory-" + agent + ".tum";
    try {
      std::filesystem::create_directories(dir);
      trajectory.WriteTum((dir / name).string(), output_frames::kLargestMap);
    } catch (const std::exception& e) {
      STITCH_LOG(ERROR) << "writing the trajectory failed: " << e.what();
    }
  }
}

std::optional<MergeSession::MapCloud> MergeSession::TakeMapCloud() {
  cloud_stale_ = false;
  const int max_points = merger_.options().map_cloud_points;
  if (max_points <= 0 || latest_placement_.empty()) return std::nullopt;
  // The refined merged map's points (fused and adjusted) for the submaps whose merged map still
  // has the same frame; the others' own points through their placement. Each map (component)
  // without the points map.ply leaves out (merger.map_export: seen by too few keyframes, or far
  // beyond the scene), so that the page frames the scene (TUM fr1/rpy: a point 2,390 units out
  // made the whole map one dot).
  struct Candidate {
    SubmapId submap;
    Eigen::Vector3d position;
  };
  std::map<int, std::vector<Candidate>> candidates;  // by component
  std::map<int, std::vector<int>> observations;
  const auto add = [&](SubmapId submap, const Eigen::Vector3d& position, const MapPoint& point) {
    const int component = latest_placement_.at(submap).component;
    candidates[component].push_back({submap, position});
    observations[component].push_back(static_cast<int>(point.observations.size()));
  };
  std::set<SubmapId> refined;
  if (refined_ && refined_->merged) {
    for (const auto& [id, point] : refined_->merged->map.points()) {
      const SubmapId submap = SubmapOf(id);
      const auto then = refined_->graph.placement.find(submap);
      const auto now = latest_placement_.find(submap);
      if (then == refined_->graph.placement.end() || now == latest_placement_.end() ||
          then->second.root != now->second.root) {
        continue;
      }
      add(submap, point.position, point);
      refined.insert(submap);
    }
  }
  for (const auto& [id, placement] : latest_placement_) {
    if (refined.count(id)) continue;
    const auto replica = merger_.submaps().find(id);
    if (replica == merger_.submaps().end()) continue;
    for (const auto& [point_id, point] : replica->second.map.points()) {
      add(id, placement.world_from_submap * point.position, point);
    }
  }
  std::map<SubmapId, std::vector<Eigen::Vector3f>> points;
  for (const auto& [id, placement] : latest_placement_) {
    if (merger_.submaps().count(id)) points[id];  // every placed submap, even one left without points
  }
  for (const auto& [component, list] : candidates) {
    std::vector<Eigen::Vector3d> positions;
    positions.reserve(list.size());
    for (const Candidate& c : list) positions.push_back(c.position);
    const std::vector<bool> keep = PointsToExport(positions, observations[component], merger_.options().map_export);
    for (size_t i = 0; i < list.size(); ++i) {
      if (keep[i]) points[list[i].submap].push_back(list[i].position.cast<float>());
    }
  }
  MapCloud cloud;
  for (const auto& [id, list] : points) cloud.points_in_maps += static_cast<int64_t>(list.size());
  const int64_t stride = std::max<int64_t>(1, (cloud.points_in_maps + max_points - 1) / max_points);
  cloud.revision = ++cloud_revision_;
  for (const auto& [id, list] : points) {
    MapCloud::Submap submap{
        id, latest_placement_.at(id).component, {}, static_cast<int>(merger_.submaps().at(id).map.num_keyframes())};
    for (size_t i = 0; i < list.size(); i += static_cast<size_t>(stride)) submap.positions.push_back(list[i]);
    cloud.submaps.push_back(std::move(submap));
  }
  return cloud;
}

const Map* MergeSession::LargestMap(const Merger::Graph& graph, const MergedMap* merged) const {
  const Map* map = merged ? &merged->map : nullptr;
  for (const auto& [id, placement] : graph.placement) {
    if (placement.component != 0 || map) continue;
    if (merger_.submaps().at(id).camera) map = &merger_.submaps().at(id).map;
  }
  return map;
}

const Camera* MergeSession::CameraOf(KeyframeId keyframe) const {
  const auto replica = merger_.submaps().find(SubmapOf(keyframe));
  return replica == merger_.submaps().end() || !replica->second.camera ? nullptr : &*replica->second.camera;
}

void MergeSession::WriteSavedMap(const Merger::Graph& graph, const MergedMap* merged) const {
  const Map* map = LargestMap(graph, merged);
  if (!map || map->num_keyframes() == 0) return;
  // Keyframes whose submap's camera never arrived cannot be used again: MakeSavedMap leaves them out.
  std::set<SubmapId> submaps;
  for (const auto& [id, keyframe] : map->keyframes()) {
    if (CameraOf(id)) submaps.insert(SubmapOf(id));
  }
  std::string description = "the merged map of submaps";
  for (SubmapId s : submaps) description += " " + SubmapName(s);
  if (prior_map_description_) description += "; the saved map was: " + *prior_map_description_;
  const SavedMap saved = MakeSavedMap(
      *map, [&](KeyframeId kf) { return CameraOf(kf); }, description, MakeSubmapId(kSavedMapAgent, 0));
  const std::string path = (std::filesystem::path(record_dir_) / "map.stitchmap").string();
  WriteMapFile(path, saved);
  STITCH_LOG(INFO) << "map.stitchmap: " << saved.map.num_keyframes() << " keyframes, " << saved.map.num_points()
                   << " points (stitch run --map)";
}

void MergeSession::WriteColmapRecord(const Merger::Graph& graph, const MergedMap* merged) const {
  // colmap/: the largest map as a COLMAP sparse model, its images named agentA-frameNNNNNN, one
  // camera per calibration its submaps' aircraft flew.
  const Map* map = LargestMap(graph, merged);
  if (!map) return;
  const auto camera_of = [&](const Keyframe& keyframe) { return CameraOf(keyframe.id); };
  const ColmapModel model = ColmapModelOf(*map, camera_of, merger_.options().map_export, ColmapImageName);
  if (model.images.empty()) return;
  WriteColmapModel(model, (std::filesystem::path(record_dir_) / "colmap").string());
  STITCH_LOG(INFO) << "colmap/: " << model.images.size() << " images, " << model.cameras.size() << " camera"
                   << (model.cameras.size() == 1 ? "" : "s") << ", " << model.points.size() << " points, reprojection "
                   << ReprojectionRms(model) << " px rms";
}

void MergeSession::WriteRecords(const Merger::Graph& graph, const MergedMap* merged) const {
  const std::filesystem::path dir(record_dir_);
  std::filesystem::create_directories(dir);
  const double min_strength = merger_.options().min_connection_strength;
  std::vector<SubmapRecord> submaps;
  for (const auto& [id, placement] : graph.placement) {
    const SubmapReplica& replica = merger_.submaps().at(id);
    submaps.push_back({id, placement.component, placement.root, replica.map.num_keyframes(), replica.map.num_points(),
                       replica.closed, placement.world_from_submap});
  }
  WriteSubmapRecords((dir / "submaps.tsv").string(), submaps);
  {
    // What the ground received of each aircraft's GNSS fixes.
    std::lock_guard<std::mutex> lock(gnss_mutex_);
    for (const auto& [agent, fixes] : gnss_) {
      GnssTrack track;
      track.source = "received by the merger from " + agent;
      for (const auto& item : fixes) track.fixes.push_back(item.second.fix);
      WriteGnssCsv((dir / (agents_.size() <= 1 ? "gnss_received.csv" : "gnss_received-" + agent + ".csv")).string(),
                   track);
    }
  }
  {
    // map.ply: the largest merged map's points in its frame, one colour per submap.
    static const uint8_t kPalette[][3] = {{30, 90, 200}, {220, 40, 40}, {40, 160, 40}, {180, 40, 180},  {220, 150, 20},
                                          {0, 140, 140}, {160, 60, 90}, {200, 110, 0}, {100, 100, 100}, {180, 180, 60}};
    std::vector<ColouredPoint> cloud;
    int colour = 0;
    std::map<SubmapId, int> colours;
    for (const auto& [id, placement] : graph.placement) {
      if (placement.component == 0) colours[id] = colour++;
    }
    std::vector<Eigen::Vector3d> positions;
    std::vector<int> observations;
    const auto add = [&](const Eigen::Vector3d& position, SubmapId submap, const MapPoint& point) {
      ColouredPoint p;
      p.position = position.cast<float>();
      const uint8_t* rgb = kPalette[colours[submap] % 10];
      p.red = rgb[0];
      p.green = rgb[1];
      p.blue = rgb[2];
      cloud.push_back(p);
      positions.push_back(position);
      observations.push_back(static_cast<int>(point.observations.size()));
    };
    if (merged) {  // fused and adjusted
      for (const auto& [id, point] : merged->map.points()) add(point.position, SubmapOf(id), point);
    } else {  // one submap: its points, each moved with a keyframe that sees it
      for (const auto& [id, placement] : graph.placement) {
        if (placement.component != 0) continue;
        const Map& map = merger_.submaps().at(id).map;
        for (const auto& [point_id, point] : map.points()) {
          Eigen::Vector3d position = placement.world_from_submap * point.position;
          if (!point.observations.empty()) {
            const KeyframeId observer = point.observations.begin()->first;
            const auto refined = graph.keyframe_poses.find(observer);
            if (refined != graph.keyframe_poses.end()) {
              position = refined->second * (map.FindKeyframe(observer)->cam_from_world * point.position);
            }
          }
          add(position, id, point);
        }
      }
    }
    // map.ply without the gross outliers a sparse map holds; map_raw.ply with every point.
    WritePly((dir / "map_raw.ply").string(), cloud, output_frames::kLargestMap);
    const std::vector<bool> keep = PointsToExport(positions, observations, merger_.options().map_export);
    std::vector<ColouredPoint> exported;
    for (size_t i = 0; i < cloud.size(); ++i) {
      if (keep[i]) exported.push_back(cloud[i]);
    }
    if (exported.size() < cloud.size()) {
      STITCH_LOG(INFO) << "map.ply: " << exported.size() << " of " << cloud.size() << " points ("
                       << cloud.size() - exported.size()
                       << " seen by too few keyframes or far beyond the scene left out; all in map_raw.ply)";
    }
    WritePly((dir / "map.ply").string(), exported, output_frames::kLargestMap);
  }
  std::vector<MergedKeyframeRecord> merged_keyframes;
  for (const auto& [id, pose] : graph.keyframe_poses) {
    const Keyframe* keyframe = merger_.submaps().at(SubmapOf(id)).map.FindKeyframe(id);
    merged_keyframes.push_back({id, graph.placement.at(SubmapOf(id)).component, pose,
                                keyframe ? keyframe->frame_index : -1, keyframe ? keyframe->t_ns : 0});
  }
  WriteMergedKeyframeRecords((dir / "keyframes_merged.tsv").string(), merged_keyframes);
  std::vector<SubmapEdgeRecord> edges;
  int outvoted = 0, refused_edges = 0;
  for (const SubmapEdge& e : graph.edges) {
    edges.push_back({e.a, e.b, e.strength, e.connected_frames, e.map_points, e.disagreeing_frames, e.median_angle_deg,
                     e.agreement, EdgeStatus(e, graph.tree, min_strength)});
    outvoted += e.disagreeing_frames;
    refused_edges += !e.refused.empty();
  }
  WriteSubmapEdgeRecords((dir / "edges.tsv").string(), edges);
  std::vector<ConnectionRecord> connections;
  for (const auto* list : {&merger_.connections(), &merger_.refused(), &merger_.loops()}) {
    for (const ConnectedFrame& c : *list) {
      ConnectionRecord r{c.keyframe_a, c.keyframe_b, c.map_points, c.median_angle_deg, c.b_from_a};
      r.verified_by = VerifiedByName(c.geometry.verified_by);
      r.bearing_spread_a = c.geometry.bearing_spread_a;
      r.bearing_spread_b = c.geometry.bearing_spread_b;
      r.line_ratio = c.geometry.line_ratio;
      r.depth_disagreement = c.geometry.depth_disagreement;
      r.verdict = ConnectionVerdict(c, graph.edges, graph.tree, min_strength);
      connections.push_back(r);
    }
  }
  WriteConnectionRecords((dir / "connections.tsv").string(), connections);
  WriteSubmapGraphDot((dir / "graph.dot").string(), submaps, edges);
  WriteSubmapGraphPng((dir / "graph.png").string(), submaps, edges);
  WriteMergeLog((dir / "merge_log.tsv").string(), merge_log_);
  WriteRetrievalRecords((dir / "retrieval.tsv").string(), merger_.retrievals());
  STITCH_LOG(INFO) << "wrote the submap graph (" << graph.placement.size() << " submaps, " << graph.edges.size()
                   << " edges, " << graph.tree.size() << " merges, " << refused_edges << " edges refused, " << outvoted
                   << " connected frames outvoted by their pair's others, " << merger_.refused().size()
                   << " refused as degenerate) to " << record_dir_;
}

}  // namespace stitch
