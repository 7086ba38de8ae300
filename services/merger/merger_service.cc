#include "services/merger/merger_service.h"

#include <algorithm>
#include <set>

#include "services/common/convert.h"
#include "services/common/map_convert.h"
#include "services/merger/merger_messages.h"
#include "stitch/submap_request_t.hpp"
#include "stitch/util/log.h"
#include "stitch/util/time.h"

namespace stitch {

namespace {
// Between two map clouds while submaps grow (a refinement publishes one at once): at least this
// long, and at least this many times what the last one took to make, so that the live view costs
// the merger at most a tenth of its time on a large map.
constexpr double kMinCloudInterval_s = 0.1;
constexpr double kCloudCostFactor = 10.0;
// Lines of the merge log each global map carries.
constexpr size_t kGlobalMapLogLines = 100;
}  // namespace

MergerService::MergerService(lcm::LCM* lcm, bus::Publisher* publisher, const MergerOptions& options,
                             const OrbOptions& orb, const Vocabulary* vocabulary, std::string record_dir,
                             const std::string& state_dir, std::vector<std::string> agents)
    : publisher_(publisher),
      pyramid_(ScalePyramid::From(orb)),
      agents_(agents.empty() ? std::vector<std::string>{publisher->agent()} : std::move(agents)),
      session_(options, vocabulary, pyramid_, record_dir, agents_),
      receiver_(ReceiverOptions{options.request_resends, options.resend_interval_s}),
      subscriber_(lcm, publisher->authenticator()),
      // Submap updates are state that matters: a generous queue, and a loud log if it overflows.
      queue_(20000, BoundedQueue<std::unique_ptr<stitch::submap_update_t>>::WhenFull::kDropOldest),
      pictures_(record_dir) {
  session_.OnGraph([this](const Merger::Graph& graph) { PublishGlobalMap(graph); });
  std::set<std::string> submap_channels;
  for (const std::string& agent : agents_) {
    submap_channels.insert(bus::Channel(agent, bus::kSubmap));
    subscriber_.Subscribe<stitch::submap_update_t>(
        bus::Channel(agent, bus::kSubmap), [this](std::unique_ptr<stitch::submap_update_t> update, const std::string&) {
          ++received_;
          last_receive_ = MonotonicSeconds();
          if (queue_.Push(std::move(update))) {
            ++rejected_;
            STITCH_LOG(ERROR) << "merger queue full: dropped the oldest submap update";
          }
        });
    subscriber_.Subscribe<stitch::frame_pose_t>(
        bus::Channel(agent, bus::kPose), [this](std::unique_ptr<stitch::frame_pose_t> message, const std::string& on) {
          std::string why;
          try {
            TrackedFramePose pose;
            pose.world_from_cam = FromFloatPose(message->cam_from_submap, "frame_pose cam_from_submap").Inverse();
            pose.cam_from_reference = FromFloatPose(message->cam_from_reference, "frame_pose cam_from_reference");
            pose.frame_index = message->frame_index;
            pose.t_ns = message->t_ns;
            pose.submap_id = message->submap_id;
            pose.reference_keyframe = message->reference_keyframe;
            if (session_.AddFramePose(message->header.agent, pose, &why)) return;
          } catch (const Error& e) {
            why = e.what();
          }
          subscriber_.Reject(on, why);
        });
    subscriber_.Subscribe<stitch::keyframe_image_t>(
        bus::Channel(agent, bus::kKeyframeImage),
        [this](std::unique_ptr<stitch::keyframe_image_t> message, const std::string& on) {
          std::string why;
          try {
            const KeyframePicture picture = FromMessage(*message);
            if (!pictures_.Add(picture, &why)) {
              STITCH_LOG(WARNING) << "a keyframe picture not kept: " << why;
            }
            if (!session_.AddKeyframePicture(picture, &why)) {
              STITCH_LOG(WARNING) << "a keyframe picture not laid: " << why;
            }
            return;  // the picture was right; the disk or the queue was not
          } catch (const Error& e) {
            why = e.what();
          }
          subscriber_.Reject(on, why);
        });
    subscriber_.Subscribe<stitch::gnss_fix_t>(
        bus::Channel(agent, bus::kGnss), [this](std::unique_ptr<stitch::gnss_fix_t> message, const std::string& on) {
          std::string why;
          if (AddGnssFix(*message, &why)) {
            Journal(*message);
          } else {
            subscriber_.Reject(on, why);
          }
        });
  }
  heartbeat_ = std::make_unique<Heartbeat>(publisher_, "merger", [this] {
    return Heartbeat::Counts{received_.load(), processed_.load(), subscriber_.rejected() + rejected_.load()};
  });
  if (!state_dir.empty()) journal_ = std::make_unique<UpdateJournal>(state_dir, submap_channels);
}

MergerService::~MergerService() {
  Stop();
}

void MergerService::Start() {
  if (running_.exchange(true)) return;
  if (journal_) {
    // Resume: what the journal holds goes through the merger again (updates are idempotent), with
    // one refinement at the end instead of one per closed submap.
    const Stopwatch clock;
    recovering_ = true;
    const int64_t count = journal_->Recover([this](const stitch::submap_update_t& update) { Process(update, true); },
                                            [this](const stitch::gnss_fix_t& fix) {
                                              std::string why;
                                              if (!AddGnssFix(fix, &why)) {
                                                STITCH_LOG(WARNING) << "a GNSS fix in the journal refused: " << why;
                                              }
                                            });
    recovering_ = false;
    if (count > 0) {
      if (session_.any_closed_whole()) Refine("resumed from the journal");
      STITCH_LOG(INFO) << "resumed from " << journal_->path() << ": " << count << " submap updates, "
                       << session_.merger().submaps().size() << " submaps, in " << clock.ElapsedMs() << " ms";
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
  if (session_.Finish()) PublishMapCloud();  // the last refinement's points
  PublishMosaicTiles();                      // the mosaic on the refined map
  heartbeat_->SetState(stitch::service_status_t::STATE_FINISHED);
  heartbeat_->Stop();
}

void MergerService::Work() {
  while (true) {
    auto update = queue_.Pop(std::chrono::milliseconds(100));
    if (update) Process(**update);
    RequestWhatWasLost();
    session_.WriteLiveTrajectoryIfDue();
    session_.UpdateMosaicIfDue();
    PublishMosaicTiles();
    if (session_.map_cloud_stale() &&
        MonotonicSeconds() - cloud_published_at_ >= std::max(kMinCloudInterval_s, kCloudCostFactor * cloud_cost_s_)) {
      PublishMapCloud();
    }
    if (!update && queue_.closed()) return;
  }
}

bool MergerService::AddGnssFix(const stitch::gnss_fix_t& message, std::string* why) {
  try {
    return session_.AddGnssFix(message.header.agent, FromMessage(message), why);
  } catch (const Error& e) {
    *why = e.what();
    return false;
  }
}

template <class Message>
void MergerService::Journal(const Message& message) {
  if (!journal_ || journal_failed_) return;
  try {
    journal_->Append(message);
  } catch (const Error& e) {
    if (!journal_failed_.exchange(true)) {  // keep merging; a restart would now lose what follows
      STITCH_LOG(ERROR) << e.what() << "; the merger goes on without persisting its store";
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
  const std::string& agent = message.header.agent;
  std::string why;
  if (!from_journal && !recovering_ && !receiver_.PlausibleRevision(agent, message.revision, &why)) {
    subscriber_.Reject(bus::Channel(agent, bus::kSubmap), why);
    return;
  }
  if (!from_journal) Journal(message);
  const MergeSession::Applied applied = session_.Apply(update, agent, message.part == 0);
  if (!applied.accepted) {
    ++rejected_;
    STITCH_LOG(WARNING) << "rejected an update of submap " << SubmapName(update.submap) << " from " << agent << ": "
                        << applied.refused;
    return;
  }
  ++processed_;
  const auto replica = session_.merger().submaps().find(update.submap);
  const bool final_state_whole = receiver_.Received(
      update, message.part, message.num_parts,
      replica == session_.merger().submaps().end() ? nullptr : &replica->second, applied.missing.size());
  // A closed submap changes the merged map for good: refine it now (pose graph, fused points,
  // bundle adjustment) in this worker, while the subscriber keeps queueing updates, once its
  // final state has arrived whole (every part of the closing update).
  if (final_state_whole && session_.FirstWholeFinalState(update.submap) && !recovering_) {
    RequestWhatWasLost();  // before the refinement's seconds: the mapper may be about to stop
    Refine("submap " + SubmapName(update.submap) + " closed");
  }
}

void MergerService::RequestWhatWasLost() {
  for (const DeliveryRequest& request : receiver_.Requests(session_.merger().submaps())) {
    stitch::submap_request_t message = ToMessage(request);
    const auto agent = session_.agent_of().find(request.submap);
    publisher_->Publish(
        bus::Channel(agent != session_.agent_of().end() ? agent->second : publisher_->agent(), bus::kSubmapRequest),
        &message);
    if (!request.complete) ++requests_;
  }
  keyframes_missing_ = receiver_.keyframes_missing();
}

void MergerService::Refine(const std::string& why) {
  session_.Refine(why);
  PublishMapCloud();
}

void MergerService::PublishGlobalMap(const Merger::Graph& graph) {
  stitch::global_map_t m =
      ToGlobalMapMessage(graph, session_.merger().submaps(), session_.agent_of(), publisher_->agent(),
                         session_.merge_log(), kGlobalMapLogLines, session_.gnss_origin());
  m.revision = ++revision_;
  publisher_->Publish(bus::Channel(publisher_->agent(), bus::kGlobalMap), &m);
}

void MergerService::PublishMosaicTiles() {
  const MergeSession::MosaicTiles taken = session_.TakeMosaicTiles();
  for (const LiveMosaicTile& tile : taken.tiles) {
    stitch::mosaic_tile_t message = ToMessage(tile, taken.newest_picture_utime);
    publisher_->Publish(bus::Channel(publisher_->agent(), bus::kMosaicTile), &message);
  }
}

void MergerService::PublishMapCloud() {
  const double started = MonotonicSeconds();
  const std::optional<MergeSession::MapCloud> cloud = session_.TakeMapCloud();
  if (cloud) {
    stitch::map_cloud_t message = ToMessage(*cloud);
    publisher_->Publish(bus::Channel(publisher_->agent(), bus::kMapCloud), &message);
  }
  cloud_published_at_ = MonotonicSeconds();
  cloud_cost_s_ = cloud_published_at_ - started;
}

}  // namespace stitch
