#include "services/merger/merger_service.h"

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "services/common/convert.h"
#include "services/common/map_convert.h"
#include "stitch/global_map_t.hpp"
#include "stitch/io/colmap_model.h"
#include "stitch/io/image_file.h"
#include "stitch/io/ply.h"
#include "stitch/io/trajectory.h"
#include "stitch/map/map_export.h"
#include "stitch/map_cloud_t.hpp"
#include "stitch/submap_request_t.hpp"
#include "stitch/util/log.h"
#include "stitch/util/text_file.h"
#include "stitch/util/time.h"

namespace stitch {

namespace {
// How far past an aircraft's newest revision an update may be: the mapper counts one revision per
// update it makes (a few per keyframe), and makes some the link never carries (thinned, lost).
// A jump may be this many, plus this many per second since the newest arrived.
constexpr int64_t kMaxRevisionJump = 1000;
constexpr int64_t kMaxRevisionsPerSecond = 100;
// Frames of the pose stream kept per aircraft: 9 hours at 30 fps.
constexpr size_t kMaxFramePoses = 1'000'000;
// Between two map clouds while submaps grow (a refinement publishes one at once).
constexpr double kCloudInterval_s = 10.0;
// Merges rolled back by the check after placement in one refinement, at most (each round solves
// and adjusts the largest map again).
constexpr int kMaxRollbacksPerRefinement = 3;
// Lines of the merge log each global map carries.
constexpr size_t kGlobalMapLogLines = 100;
}  // namespace

MergerService::MergerService(lcm::LCM* lcm, bus::Publisher* publisher, const MergerOptions& options,
                             const OrbOptions& orb, const Vocabulary* vocabulary, std::string record_dir,
                             const std::string& state_dir, std::vector<std::string> agents)
    : publisher_(publisher),
      pyramid_(ScalePyramid::From(orb)),
      record_dir_(std::move(record_dir)),
      merger_(options, vocabulary, pyramid_),
      subscriber_(lcm),
      // Submap updates are state that matters: a generous queue, and a loud log if it overflows.
      queue_(20000, BoundedQueue<std::unique_ptr<stitch::submap_update_t>>::WhenFull::kDropOldest) {
  agents_ = agents.empty() ? std::vector<std::string>{publisher_->agent()} : std::move(agents);
  std::set<std::string> channels;
  for (const std::string& agent : agents_) {
    channels.insert(bus::Channel(agent, bus::kSubmap));
    subscriber_.Subscribe<stitch::submap_update_t>(
        bus::Channel(agent, bus::kSubmap), [this](std::unique_ptr<stitch::submap_update_t> update, const std::string&) {
          ++received_;
          last_receive_ = MonotonicSeconds();
          if (queue_.Push(std::move(update))) {
            ++rejected_;
            STITCH_LOG(ERROR) << "merger queue full: dropped the oldest submap update";
          }
        });
  }
  submap_channels_ = channels;
  for (const std::string& agent : agents_) {
    subscriber_.Subscribe<stitch::frame_pose_t>(
        bus::Channel(agent, bus::kPose), [this](std::unique_ptr<stitch::frame_pose_t> pose, const std::string& on) {
          std::string why;
          if (!TakePose(*pose, &why)) subscriber_.Reject(on, why);
        });
  }
  heartbeat_ = std::make_unique<Heartbeat>(publisher_, "merger", [this] {
    return Heartbeat::Counts{received_.load(), processed_.load(), subscriber_.rejected() + rejected_.load()};
  });
  if (!state_dir.empty()) journal_ = std::make_unique<UpdateJournal>(state_dir, submap_channels_);
}

MergerService::~MergerService() {
  Stop();
}

SubmapUpdateLogRead MergerService::Replay(const std::string& log_path) {
  recovering_ = true;
  const SubmapUpdateLogRead read = ReadSubmapUpdateLog(
      log_path, submap_channels_, [this](const stitch::submap_update_t& update) { Process(update); });
  recovering_ = false;
  return read;
}

void MergerService::Start() {
  if (running_.exchange(true)) return;
  if (journal_) {
    // Resume: what the journal holds goes through the merger again (updates are idempotent), with
    // one refinement at the end instead of one per closed submap.
    const Stopwatch clock;
    recovering_ = true;
    const int64_t count = journal_->Recover([this](const stitch::submap_update_t& update) { Process(update, true); });
    recovering_ = false;
    if (count > 0) {
      if (!refined_closed_.empty()) Refine("resumed from the journal");
      STITCH_LOG(INFO) << "resumed from " << journal_->path() << ": " << count << " submap updates, "
                       << merger_.submaps().size() << " submaps, in " << clock.ElapsedMs() << " ms";
    }
  }
  worker_ = std::thread([this] { Work(); });
  heartbeat_->Start();
  heartbeat_->SetState(stitch::service_status_t::STATE_RUNNING);
}

void MergerService::Stop() {
  if (!running_.exchange(false)) return;
  queue_.Close();
  if (worker_.joinable()) worker_.join();
  const bool refine_now = !refined_ || refined_at_ != processed_.load();
  if (refine_now) Refine("the run ended");  // writes the records
  for (const auto& [id, replica] : merger_.submaps()) {
    const SubmapCompleteness c = CompletenessOf(replica);
    if (c.missing == 0 && replica.closed) continue;
    STITCH_LOG(WARNING) << "submap " << SubmapName(id) << " is incomplete on the ground: " << c.missing << " of its "
                        << c.listed << " keyframes" << (replica.closed ? "" : " and its final state")
                        << " never arrived; the map holds what did";
  }
  const Merger::Graph& graph = refined_->graph;
  const std::optional<MergedMap>& merged = refined_->merged;
  if (!record_dir_.empty()) {
    try {
      if (!refine_now) WriteRecords(graph, merged ? &*merged : nullptr);
      // The COLMAP model, a product for after the flight, only at the end.
      WriteColmapRecord(graph, merged ? &*merged : nullptr);
    } catch (const std::exception& e) {
      STITCH_LOG(ERROR) << "writing the merger's records failed: " << e.what();
    }
  }
  WriteLiveTrajectory();
  heartbeat_->SetState(stitch::service_status_t::STATE_FINISHED);
  heartbeat_->Stop();
}

std::optional<MergedMap> MergerService::MergeLargestMap(Merger::Graph* graph) const {
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
  MergedMap merged = AssembleMergedMap(merger_.submaps(), graph->placement, graph->keyframe_poses, graph->agreeing, 0,
                                       pyramid_, replica.camera->Intrinsics(), merger_.options().merged_map);
  for (const auto& [id, pose] : merged.keyframe_poses) graph->keyframe_poses[id] = pose;
  const BundleAdjustmentReport& ba = merged.bundle_adjustment;
  STITCH_LOG(INFO) << "merged map of " << members << " submaps with " << loops
                   << " loops: " << merged.map.num_keyframes() << " keyframes, " << merged.map.num_points()
                   << " points; fused " << merged.points_fused_by_connection << " points from connected frames and "
                   << merged.points_fused_by_projection << " by projection; bundle adjustment " << ba.initial_rms_px
                   << " -> " << ba.final_rms_px << " px rms (" << ba.observations << " observations, "
                   << ba.outliers_removed << " outliers removed) in " << clock.ElapsedMs() << " ms";
  for (const auto& [pair, junction] : merged.junctions) {
    STITCH_LOG(INFO) << "junction " << SubmapName(pair.first) << "-" << SubmapName(pair.second) << ": " << junction.kept
                     << " of " << junction.joined << " joining observations kept";
  }
  return merged;
}

void MergerService::Work() {
  while (true) {
    auto update = queue_.Pop(std::chrono::milliseconds(100));
    if (update) Process(**update);
    RequestWhatWasLost();
    const double interval = merger_.options().live_outputs_interval_s;
    if (interval > 0 && MonotonicSeconds() - trajectory_written_at_ >= interval) WriteLiveTrajectory();
    if (cloud_stale_ && MonotonicSeconds() - cloud_published_at_ >= kCloudInterval_s) PublishMapCloud();
    if (!update && queue_.closed()) return;
  }
}

bool MergerService::TakePose(const stitch::frame_pose_t& message, std::string* why) {
  TrackedFramePose pose;
  try {
    pose.world_from_cam = FromFloatPose(message.cam_from_submap, "frame_pose cam_from_submap").Inverse();
    pose.cam_from_reference = FromFloatPose(message.cam_from_reference, "frame_pose cam_from_reference");
  } catch (const Error& e) {
    *why = e.what();
    return false;
  }
  const SubmapId submap(message.submap_id);
  if (message.frame_index < 0 || message.t_ns < 0) {
    *why = "negative frame index or time";
    return false;
  }
  if (!submap.valid() || SubmapOf(submap) != submap) {
    *why = "names no submap (" + std::to_string(message.submap_id) + ")";
    return false;
  }
  if (message.reference_keyframe != -1 &&
      (message.reference_keyframe < 0 || SubmapOf(KeyframeId(message.reference_keyframe)) != submap)) {
    *why = "its reference keyframe is not of its submap";
    return false;
  }
  pose.frame_index = message.frame_index;
  pose.t_ns = message.t_ns;
  pose.submap_id = message.submap_id;
  pose.reference_keyframe = message.reference_keyframe;
  std::lock_guard<std::mutex> lock(poses_mutex_);
  if (poses_pending_.size() >= kMaxFramePoses) {
    *why = "the worker is " + std::to_string(kMaxFramePoses) + " poses behind";
    return false;
  }
  poses_pending_.emplace_back(message.header.agent, pose);
  ++poses_received_;
  return true;
}

void MergerService::WriteLiveTrajectory() {
  trajectory_written_at_ = MonotonicSeconds();
  {
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
    const std::string name = agents_.size() == 1 ? "trajectory.tum" : "trajectory-" + agent + ".tum";
    try {
      std::filesystem::create_directories(dir);
      trajectory.WriteTum((dir / name).string());
    } catch (const std::exception& e) {
      STITCH_LOG(ERROR) << "writing the trajectory failed: " << e.what();
    }
  }
}

void MergerService::Process(const stitch::submap_update_t& message, bool from_journal) {
  SubmapUpdate update;
  try {
    update = FromMessage(message, pyramid_);
  } catch (const Error& e) {
    ++rejected_;
    STITCH_LOG(WARNING) << "rejected a submap update: " << e.what();
    return;
  }
  if (!from_journal && !recovering_ && !PlausibleRevision(message)) return;
  if (journal_ && !from_journal && !journal_failed_) {
    try {
      journal_->Append(message);
    } catch (const Error& e) {
      journal_failed_ = true;  // keep merging; a restart would now lose what follows
      STITCH_LOG(ERROR) << e.what() << "; the merger goes on without persisting its store";
    }
  }
  // Two aircraft with the same agent number would mix their submaps: keep the first's.
  const auto [known, fresh] = agent_of_.try_emplace(update.submap, message.header.agent);
  if (!fresh && known->second != message.header.agent) {
    ++rejected_;
    STITCH_LOG(WARNING) << "rejected an update of submap " << SubmapName(update.submap) << " from "
                        << message.header.agent << ": that submap is " << known->second
                        << "'s (two aircraft with one agent_number?)";
    return;
  }
  const std::vector<KeyframeId> missing = merger_.Apply(update);
  ++processed_;
  last_update_[update.submap] = MonotonicSeconds();
  // A final state comes in parts, the first with the manifest and the removals: it is whole once
  // every part of its revision has arrived, in whatever order (its last part alone, arrived first
  // or with the first lost, left the merger judging the submap by an older manifest).
  bool final_state_whole = false;
  if (update.closed && update.full_state && message.part >= 0 && message.part < message.num_parts) {
    FinalStateParts& parts = final_parts_[update.submap];
    if (message.revision > parts.revision) parts = FinalStateParts{message.revision, message.num_parts, {}};
    if (message.revision == parts.revision && message.num_parts == parts.num_parts &&
        parts.received.insert(message.part).second) {
      final_state_whole = static_cast<int32_t>(parts.received.size()) == parts.num_parts;
    }
  }
  if (!missing.empty() && final_state_whole) {
    STITCH_LOG(WARNING) << "submap " << SubmapName(update.submap) << " closed with " << missing.size()
                        << " keyframes never received (lost on the way"
                        << (merger_.options().request_resends ? "; asking for them again)" : ")");
  }
  const auto replica = merger_.submaps().find(update.submap);
  if (replica == merger_.submaps().end() || !replica->second.closed) {
    final_whole_.erase(update.submap);  // reopened (or not closed yet)
  } else if (final_state_whole) {
    final_whole_.insert(update.submap);
    confirmed_complete_.erase(update.submap);  // a final state sent again is confirmed again
  }
  const bool newly_closed = update.closed && !closed_seen_[update.submap];
  closed_seen_[update.submap] = update.closed;
  if (merger_.connections().size() != connections_seen_ || newly_closed || message.part == 0) {
    connections_seen_ = merger_.connections().size();
    OnGraphChange(newly_closed ? "submap " + SubmapName(update.submap) + " closed"
                               : "keyframe of submap " + SubmapName(update.submap));
  }
  // A closed submap changes the merged map for good: refine it now (pose graph, fused points,
  // bundle adjustment) in this worker, while the subscriber keeps queueing updates...
  // ...once its final state has arrived whole (every part of the closing update).
  if (final_state_whole && refined_closed_.insert(update.submap).second && !recovering_) {
    RequestWhatWasLost();  // before the refinement's seconds: the mapper may be about to stop
    Refine("submap " + SubmapName(update.submap) + " closed");
  }
}

bool MergerService::PlausibleRevision(const stitch::submap_update_t& message) {
  const double now = MonotonicSeconds();
  const auto newest = newest_revision_.find(message.header.agent);
  int64_t allowed = std::numeric_limits<int32_t>::max();
  if (newest != newest_revision_.end()) {
    const double waited_s = std::max(0.0, now - newest->second.heard_at);
    allowed = newest->second.revision + kMaxRevisionJump +
              static_cast<int64_t>(std::min(waited_s, 1e7) * static_cast<double>(kMaxRevisionsPerSecond));
  }
  if (message.revision < 0 || message.revision > allowed) {
    // Stale from then on, every later real update of the submap would leave it as it was.
    subscriber_.Reject(
        bus::Channel(message.header.agent, bus::kSubmap),
        "jumps to revision " + std::to_string(message.revision) + " from " +
            (newest == newest_revision_.end() ? std::string("none") : std::to_string(newest->second.revision)));
    return false;
  }
  if (newest == newest_revision_.end()) {
    newest_revision_[message.header.agent] = {message.revision, now};
  } else if (message.revision > newest->second.revision) {
    newest->second = {message.revision, now};
  }
  return true;
}

void MergerService::RequestWhatWasLost() {
  const MergerOptions& options = merger_.options();
  const double now = MonotonicSeconds();
  std::map<int, SubmapId> newest;  // per aircraft
  for (const auto& [id, replica] : merger_.submaps()) {
    SubmapId& n = newest[AgentNumber(id)];
    if (!n.valid() || n < id) n = id;
  }
  const auto publish = [&](SubmapId id, stitch::submap_request_t* request) {
    const auto agent = agent_of_.find(id);
    publisher_->Publish(
        bus::Channel(agent != agent_of_.end() ? agent->second : publisher_->agent(), bus::kSubmapRequest), request);
  };
  int64_t missing_total = 0;
  std::map<KeyframeId, double> missing_since;
  for (const auto& [id, replica] : merger_.submaps()) {
    stitch::submap_request_t request{};
    request.submap_id = id.value;
    const size_t missing_before = missing_since.size();
    // The final state has arrived whole: what it lists and is not here was lost.
    const bool final_whole = replica.closed && final_whole_.count(id) > 0;
    for (KeyframeId kf : replica.manifest) {
      if (replica.map.FindKeyframe(kf)) continue;
      ++missing_total;
      // The parts of one update arrive within milliseconds: a keyframe is lost when it stays
      // missing for a while.
      const auto since = missing_since_.find(kf);
      const double first = since != missing_since_.end() ? since->second : now;
      missing_since[kf] = first;
      if (final_whole || now - first > 0.3 * options.resend_interval_s) request.keyframe_ids.push_back(kf.value);
    }
    if (options.request_resends && final_whole && missing_since.size() == missing_before &&
        confirmed_complete_.insert(id).second) {
      // Nothing missing: the mapper, stopping, need not wait for more requests about it.
      stitch::submap_request_t complete{};
      complete.submap_id = id.value;
      complete.complete = true;
      publish(id, &complete);
      STITCH_LOG(INFO) << "holds submap " << SubmapName(id) << " whole (" << replica.manifest.size()
                       << " keyframes): told its mapper";
    }
    // Left open while a newer submap of its aircraft goes on, and quiet: its final state was lost
    // (a submap the tracker reopened is not quiet). Closed, but its final state never arrived in
    // all its parts, and quiet: a part was lost; asked for again, or its mapper would keep it
    // (never confirmed whole) and the merger its partial state, to the end of the flight.
    const auto heard = last_update_.find(id);
    const bool quiet = heard == last_update_.end() || now - heard->second > 3 * options.resend_interval_s;
    request.full_state = quiet && (replica.closed ? !final_whole : newest[AgentNumber(id)] != id);
    if (!options.request_resends || (request.keyframe_ids.empty() && !request.full_state)) continue;
    double& last = last_request_[id];
    if (now - last < options.resend_interval_s) continue;
    last = now;
    request.num_keyframes = static_cast<int32_t>(request.keyframe_ids.size());
    publish(id, &request);
    ++requests_;
    STITCH_LOG(INFO) << "asked for submap " << SubmapName(id) << " again: " << request.num_keyframes
                     << " keyframes missing" << (request.full_state ? ", final state missing" : "");
  }
  keyframes_missing_ = missing_total;
  missing_since_.swap(missing_since);
}

void MergerService::Refine(const std::string& why) {
  const Stopwatch clock;
  const Merger::Reverification again = merger_.ReverifyStaleConnections();
  if (again.reverified > 0) {
    STITCH_LOG(INFO) << "verified " << again.reverified
                     << " connected frames again on their submaps' newer points: " << again.changed << " moved, "
                     << again.stale << " could not be (kept as stale: they count where the fresh ones agree)";
    OnGraphChange("connected frames verified again (" + why + ")");
  }
  Refined refined{merger_.Solve(/*refine=*/true), std::nullopt};
  refined.merged = MergeLargestMap(&refined.graph);
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
    refined = Refined{merger_.Solve(/*refine=*/true), std::nullopt};
    refined.merged = MergeLargestMap(&refined.graph);
  }
  PublishGlobalMap(refined.graph);
  refined_ = std::move(refined);
  refined_at_ = processed_.load();
  if (!record_dir_.empty() && !recovering_) {
    // The last good map on disk at every refinement, not only at the end.
    try {
      WriteRecords(refined_->graph, refined_->merged ? &*refined_->merged : nullptr);
    } catch (const std::exception& e) {
      STITCH_LOG(ERROR) << "writing the merger's records failed: " << e.what();
    }
    WriteLiveTrajectory();
  }
  PublishMapCloud();
  STITCH_LOG(INFO) << "refined the merged maps (" << why << ") in " << clock.ElapsedMs() << " ms";
}

void MergerService::OnGraphChange(const std::string& event) {
  const Merger::Graph graph = merger_.Solve();
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
  const std::string row = current_map + "\t" + stack + "\t" + maps;
  if (row == last_stack_) return;
  last_stack_ = row;
  merge_log_.push_back({event, current_map, stack, maps});
  STITCH_LOG(INFO) << event << ": current map " << current_map << "; unconnected " << (stack.empty() ? "-" : stack);
  PublishGlobalMap(graph);
}

void MergerService::PublishGlobalMap(const Merger::Graph& graph) {
  latest_placement_ = graph.placement;
  trajectory_stale_ = true;
  cloud_stale_ = true;
  stitch::global_map_t m{};
  m.revision = ++revision_;
  for (const auto& [id, placement] : graph.placement) {
    const SubmapReplica& replica = merger_.submaps().at(id);
    stitch::submap_placement_t p{};
    const auto agent = agent_of_.find(id);
    p.agent = agent != agent_of_.end() ? agent->second : publisher_->agent();
    p.submap_id = id.value;
    p.component = placement.component;
    p.world_from_submap = ToMessage(placement.world_from_submap);
    p.num_keyframes = static_cast<int32_t>(replica.map.num_keyframes());
    p.num_points = static_cast<int32_t>(replica.map.num_points());
    p.closed = replica.closed;
    m.submaps.push_back(p);
  }
  m.num_submaps = static_cast<int32_t>(m.submaps.size());
  for (const SubmapEdge& e : graph.edges) {
    stitch::submap_edge_t edge{};
    edge.submap_a = e.a.value;
    edge.submap_b = e.b.value;
    edge.strength = e.strength;
    edge.connected_frames = e.connected_frames;
    edge.map_points = e.map_points;
    edge.median_angle_deg = e.median_angle_deg;
    edge.in_spanning_tree = InTree(e, graph.tree);
    edge.b_from_a = ToMessage(e.b_from_a);
    edge.refused = e.refused;
    m.edges.push_back(edge);
  }
  m.num_edges = static_cast<int32_t>(m.edges.size());
  // The refined keyframe poses (after the pose graph and the bundle adjustment), when there are;
  // frames between keyframes follow the nearest one.
  for (const auto& [id, pose] : graph.keyframe_poses) {
    const Keyframe* keyframe = merger_.submaps().at(SubmapOf(id)).map.FindKeyframe(id);
    if (!keyframe) continue;
    stitch::trajectory_pose_t p{};
    p.frame_index = keyframe->frame_index;
    p.t_ns = keyframe->t_ns;
    p.submap_id = SubmapOf(id).value;
    p.component = graph.placement.at(SubmapOf(id)).component;
    p.is_keyframe = true;
    p.world_from_cam = ToMessage(pose);
    m.trajectory.push_back(p);
  }
  m.num_poses = static_cast<int32_t>(m.trajectory.size());
  for (size_t i = merge_log_.size() > kGlobalMapLogLines ? merge_log_.size() - kGlobalMapLogLines : 0;
       i < merge_log_.size(); ++i) {
    const MergeLogRecord& r = merge_log_[i];
    m.merge_log.push_back(r.event + "\t" + r.current_map + "\t" + r.unconnected + "\t" + r.merged_maps);
  }
  m.num_log_lines = static_cast<int32_t>(m.merge_log.size());
  publisher_->Publish(bus::Channel(publisher_->agent(), bus::kGlobalMap), &m);
}

void MergerService::PublishMapCloud() {
  cloud_stale_ = false;
  cloud_published_at_ = MonotonicSeconds();
  const int max_points = merger_.options().map_cloud_points;
  if (max_points <= 0 || latest_placement_.empty()) return;
  // The refined merged map's points (fused and adjusted) for the submaps whose merged map still
  // has the same frame; the others' own points through their placement.
  std::map<SubmapId, std::vector<Eigen::Vector3f>> points;
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
      points[submap].push_back(point.position.cast<float>());
      refined.insert(submap);
    }
  }
  for (const auto& [id, placement] : latest_placement_) {
    if (refined.count(id)) continue;
    const auto replica = merger_.submaps().find(id);
    if (replica == merger_.submaps().end()) continue;
    std::vector<Eigen::Vector3f>& list = points[id];
    for (const auto& [point_id, point] : replica->second.map.points()) {
      list.push_back((placement.world_from_submap * point.position).cast<float>());
    }
  }
  int64_t total = 0;
  for (const auto& [id, list] : points) total += static_cast<int64_t>(list.size());
  const int64_t stride = std::max<int64_t>(1, (total + max_points - 1) / max_points);
  stitch::map_cloud_t cloud{};
  cloud.revision = ++cloud_revision_;
  cloud.points_in_maps = total;
  for (const auto& [id, list] : points) {
    int32_t count = 0;
    for (size_t i = 0; i < list.size(); i += static_cast<size_t>(stride), ++count) {
      cloud.positions.insert(cloud.positions.end(), {list[i].x(), list[i].y(), list[i].z()});
    }
    cloud.submap_ids.push_back(id.value);
    cloud.components.push_back(latest_placement_.at(id).component);
    cloud.point_counts.push_back(count);
  }
  cloud.num_submaps = static_cast<int32_t>(cloud.submap_ids.size());
  cloud.num_coordinates = static_cast<int32_t>(cloud.positions.size());
  publisher_->Publish(bus::Channel(publisher_->agent(), bus::kMapCloud), &cloud);
}

std::string ColmapImageName(const Keyframe& keyframe) {
  char name[48];
  std::snprintf(name, sizeof(name), "agent%d-frame%06d", AgentNumber(SubmapOf(keyframe.id)), keyframe.frame_index);
  return name;
}

void MergerService::WriteColmapRecord(const Merger::Graph& graph, const MergedMap* merged) const {
  // colmap/: the largest map as a COLMAP sparse model, its images named agentA-frameNNNNNN
  // (`stitch export colmap` names them by the image files). One camera: the map's submaps must
  // share it.
  std::optional<Camera> camera;
  const Map* map = merged ? &merged->map : nullptr;
  for (const auto& [id, placement] : graph.placement) {
    if (placement.component != 0) continue;
    const SubmapReplica& replica = merger_.submaps().at(id);
    if (!replica.camera) continue;
    if (camera && camera->Describe() != replica.camera->Describe()) {
      STITCH_LOG(WARNING) << "no COLMAP model: the largest map's submaps come from more than one camera";
      return;
    }
    camera = replica.camera;
    if (!merged) map = &replica.map;
  }
  if (!camera || !map) return;
  const ColmapModel model = ColmapModelOf(*map, *camera, merger_.options().map_export, ColmapImageName);
  WriteColmapModel(model, (std::filesystem::path(record_dir_) / "colmap").string());
  STITCH_LOG(INFO) << "colmap/: " << model.images.size() << " images, " << model.points.size()
                   << " points, reprojection " << ReprojectionRms(model) << " px rms";
}

void MergerService::WriteRecords(const Merger::Graph& graph, const MergedMap* merged) const {
  const std::filesystem::path dir(record_dir_);
  std::filesystem::create_directories(dir);
  std::vector<SubmapRecord> submaps;
  for (const auto& [id, placement] : graph.placement) {
    const SubmapReplica& replica = merger_.submaps().at(id);
    submaps.push_back({id, placement.component, placement.root, replica.map.num_keyframes(), replica.map.num_points(),
                       replica.closed, placement.world_from_submap});
  }
  WriteSubmapRecords((dir / "submaps.tsv").string(), submaps);
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
    WritePly((dir / "map_raw.ply").string(), cloud);
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
    WritePly((dir / "map.ply").string(), exported);
  }
  std::vector<MergedKeyframeRecord> merged_keyframes;
  for (const auto& [id, pose] : graph.keyframe_poses) {
    const Keyframe* keyframe = merger_.submaps().at(SubmapOf(id)).map.FindKeyframe(id);
    merged_keyframes.push_back({id, graph.placement.at(SubmapOf(id)).component, pose,
                                keyframe ? keyframe->frame_index : -1, keyframe ? keyframe->t_ns : 0});
  }
  WriteMergedKeyframeRecords((dir / "keyframes_merged.tsv").string(), merged_keyframes);
  const double min_strength = merger_.options().min_connection_strength;
  std::vector<SubmapEdgeRecord> edges;
  for (const SubmapEdge& e : graph.edges) {
    edges.push_back({e.a, e.b, e.strength, e.connected_frames, e.map_points, e.disagreeing_frames, e.median_angle_deg,
                     e.agreement, EdgeStatus(e, graph.tree, min_strength)});
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
  {
    std::ostringstream out;
    out << "graph submaps {\n  // edge weight -C; bold: Kruskal's spanning tree\n";
    for (const auto& [id, placement] : graph.placement) {
      out << "  \"" << SubmapName(id) << "\" [label=\"" << SubmapName(id) << "\\n"
          << merger_.submaps().at(id).map.num_keyframes() << " kf, map " << placement.component << "\"];\n";
    }
    for (const SubmapEdge& e : graph.edges) {
      const bool in_tree = InTree(e, graph.tree);
      char label[128];
      std::snprintf(
          label, sizeof(label), "C=%.1f (F=%d M=%d %.0f deg%s)", e.strength, e.connected_frames, e.map_points,
          e.median_angle_deg,
          e.disagreeing_frames > 0 ? (", " + std::to_string(e.disagreeing_frames) + " outvoted").c_str() : "");
      out << "  \"" << SubmapName(e.a) << "\" -- \"" << SubmapName(e.b) << "\" [label=\"" << label
          << (e.refused.empty() ? "" : "\\nrefused: " + e.refused) << "\""
          << (in_tree             ? ", style=bold"
              : e.refused.empty() ? ", style=dashed"
                                  : ", style=dotted, color=red")
          << "];\n";
    }
    out << "}\n";
    WriteFileAtomically((dir / "graph.dot").string(), out.str());
  }
  {
    // The graph as a picture: submaps on a circle, edges with their strength.
    const int size = 640;
    cv::Mat image(size, size, CV_8UC3, cv::Scalar(255, 255, 255));
    std::map<SubmapId, cv::Point> at;
    const size_t n = graph.placement.size();
    size_t i = 0;
    for (const auto& [id, placement] : graph.placement) {
      const double angle = 2 * M_PI * static_cast<double>(i++) / std::max<size_t>(1, n) - M_PI / 2;
      at[id] = cv::Point(size / 2 + static_cast<int>(230 * std::cos(angle)),
                         size / 2 + static_cast<int>(230 * std::sin(angle)));
    }
    for (const SubmapEdge& e : graph.edges) {
      const bool in_tree = InTree(e, graph.tree);
      cv::line(image, at[e.a], at[e.b], in_tree ? cv::Scalar(40, 40, 200) : cv::Scalar(180, 180, 180), in_tree ? 3 : 1,
               cv::LINE_AA);
      char label[32];
      std::snprintf(label, sizeof(label), "%.0f", e.strength);
      cv::putText(image, label, (at[e.a] + at[e.b]) / 2, cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(0, 0, 0), 1,
                  cv::LINE_AA);
    }
    static const cv::Scalar kColours[] = {{200, 90, 30}, {40, 40, 220}, {40, 160, 40}, {180, 40, 180}, {20, 150, 220}};
    for (const auto& [id, placement] : graph.placement) {
      cv::circle(image, at[id], 22, kColours[placement.component % 5], cv::FILLED, cv::LINE_AA);
      cv::putText(image, SubmapName(id), at[id] + cv::Point(-16, 5), cv::FONT_HERSHEY_SIMPLEX, 0.45,
                  cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
    }
    cv::putText(image, "submap graph: edges labelled C, spanning tree in red, one colour per merged map",
                cv::Point(10, 20), cv::FONT_HERSHEY_SIMPLEX, 0.45, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
    WritePng((dir / "graph.png").string(), image);
  }
  WriteMergeLog((dir / "merge_log.tsv").string(), merge_log_);
  WriteRetrievalRecords((dir / "retrieval.tsv").string(), merger_.retrievals());
  int outvoted = 0, refused_edges = 0;
  for (const SubmapEdge& e : graph.edges) {
    outvoted += e.disagreeing_frames;
    refused_edges += !e.refused.empty();
  }
  STITCH_LOG(INFO) << "wrote the submap graph (" << graph.placement.size() << " submaps, " << graph.edges.size()
                   << " edges, " << graph.tree.size() << " merges, " << refused_edges << " edges refused, " << outvoted
                   << " connected frames outvoted by their pair's others, " << merger_.refused().size()
                   << " refused as degenerate) to " << record_dir_;
}

}  // namespace stitch
