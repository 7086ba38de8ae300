// Ingest, tracker and mapper services on one in-process bus (memq://), as in a single process.

#include <algorithm>
#include <atomic>
#include <filesystem>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <thread>

#include <gtest/gtest.h>

#include "services/common/convert.h"
#include "services/common/map_convert.h"
#include "services/common/secret_file.h"
#include "services/ingest/ingest_service.h"
#include "services/mapper/mapper_service.h"
#include "services/tracker/tracker_service.h"
#include "stitch/config/stitch_config.h"
#include "stitch/eval/evaluation.h"
#include "stitch/frame_ack_t.hpp"
#include "stitch/io/ply.h"
#include "stitch/keyframe_t.hpp"
#include "stitch/link_status_t.hpp"
#include "stitch/records/frame_record.h"
#include "stitch/records/keyframe_record.h"
#include "stitch/service_status_t.hpp"
#include "stitch/source/source.h"
#include "stitch/submap_request_t.hpp"
#include "stitch/submap_update_t.hpp"
#include "stitch/testing/temp_dir.h"
#include "stitch/tracking_status_t.hpp"
#include "tests/memq_dispatched.h"
#include "tests/synthetic_flight.h"

namespace stitch {
namespace {

// The services on one memq bus, playing the short flight. Subscribe test handlers on `lcm`
// between construction and Play().
struct InProcessStack {
  InProcessStack(const std::function<void(StitchConfig*)>& adjust, bool with_mapper, const std::string& record_dir)
      : config(LoadConfig(adjust)),
        vocabulary(LoadVocabulary(config)),
        lcm(bus::OpenLcm("memq://")),
        publisher(lcm.get(), "uav0", bus::BusAuthenticator::FromSetting(config.bus.key_file)),
        ingest(lcm.get(), "memq://", &publisher, config.ingest),
        tracker(lcm.get(), &publisher, config.tracker, &vocabulary,
                record_dir.empty() ? "" : record_dir + "/frames.tsv") {
    if (with_mapper)
      mapper.emplace(lcm.get(), &publisher, config.mapper, config.tracker.tracking.orb, &vocabulary, record_dir);
  }

  static StitchConfig LoadConfig(const std::function<void(StitchConfig*)>& adjust) {
    StitchConfig c = LoadStitchConfig(std::string(STITCH_SOURCE_DIR) + "/tests/short_flight.yaml");
    // A lockstep frame waits for its ack however slow the build (a sanitizer beside other tests
    // takes over 10 s for a frame whose keyframe the mapper answers late): up to 10 minutes.
    c.ingest.max_resends = 2400;
    if (adjust) adjust(&c);
    return c;
  }

  // Plays the flight with `failures`, then stops every service (the mapper writes its records).
  IngestSummary Play(const std::string& failures, int max_frames = -1) {
    bus::Dispatcher dispatcher(lcm.get());
    dispatcher.Start();
    if (mapper) mapper->Start();
    tracker.Start();
    const IngestSummary summary =
        testing::PlaySyntheticFlight(ingest, config.synthetic, failures, max_frames, &ground_truth);
    tracker.Stop();
    if (mapper) mapper->Stop();
    WaitUntilDispatched();
    dispatcher.Stop();
    return summary;
  }

  void WaitUntilDispatched() { testing::WaitUntilDispatched(lcm.get()); }

  StitchConfig config;
  Vocabulary vocabulary;
  std::unique_ptr<lcm::LCM> lcm;
  bus::Publisher publisher;
  IngestService ingest;
  TrackerService tracker;
  std::optional<MapperService> mapper;
  Trajectory ground_truth;
};

// Every tracking status the tracker publishes on `lcm`, in order; `also` sees each as it comes
// (under the lock).
class TrackingStatuses {
 public:
  explicit TrackingStatuses(lcm::LCM* lcm, std::function<void(const stitch::tracking_status_t&)> also = nullptr)
      : subscriber_(lcm), also_(std::move(also)) {
    subscriber_.Subscribe<stitch::tracking_status_t>(
        bus::Channel("uav0", bus::kTrackingStatus),
        [this](std::unique_ptr<stitch::tracking_status_t> status, const std::string&) {
          std::lock_guard<std::mutex> lock(mutex_);
          if (also_) also_(*status);
          statuses_.push_back(*status);
        });
  }
  std::vector<stitch::tracking_status_t> Get() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return statuses_;
  }

 private:
  mutable std::mutex mutex_;
  std::vector<stitch::tracking_status_t> statuses_;
  bus::Subscriber subscriber_;
  std::function<void(const stitch::tracking_status_t&)> also_;
};

// Every keyframe the mapper kept (its keyframes.tsv) is in the replica at the same pose.
void ExpectReplicaIsTheMappersSubmap(const SubmapReplica& replica, const std::string& keyframes_tsv) {
  int kept = 0;
  for (const KeyframeRecord& k : ReadKeyframeRecords(keyframes_tsv)) {
    if (k.culled) continue;
    ++kept;
    const Keyframe* keyframe = replica.map.FindKeyframe(KeyframeId(k.keyframe_id));
    ASSERT_NE(keyframe, nullptr) << k.keyframe_id;
    EXPECT_LT((keyframe->Centre() - k.world_from_cam.translation).norm(), 1e-4);
  }
  EXPECT_EQ(static_cast<size_t>(kept), replica.map.num_keyframes());
}

// The bus names a tracking state as the core does (the bus library links no algorithm, so it
// keeps its own names: this holds them to the core's).
TEST(TrackingStates, EveryStateHasTheCoresNameOnTheBus) {
  for (TrackingState state : {TrackingState::kInitializing, TrackingState::kOk, TrackingState::kLost,
                              TrackingState::kSkipped, TrackingState::kNotTracked}) {
    EXPECT_STREQ(MessageStateName(ToMessageState(state)), TrackingStateName(state));
  }
  EXPECT_STREQ(MessageStateName(77), "UNKNOWN");
}

TEST(ServicesInProcess, IngestTrackerAndMapperTrackAShortFlightOverMemq) {
  testing::TempDir dir;
  InProcessStack stack(nullptr, /*with_mapper=*/true, dir.path().string());
  // What a merger would receive: every submap rebuilt from the SUBMAP channel.
  const ScalePyramid pyramid = ScalePyramid::From(stack.config.tracker.tracking.orb);
  std::map<SubmapId, SubmapReplica> replicas;
  std::vector<KeyframeId> missing;
  bus::Subscriber merger_side(stack.lcm.get());
  merger_side.Subscribe<stitch::submap_update_t>(
      bus::Channel("uav0", bus::kSubmap), [&](std::unique_ptr<stitch::submap_update_t> message, const std::string&) {
        const SubmapUpdate update = FromMessage(*message, pyramid);
        auto it = replicas.try_emplace(update.submap, update.submap, pyramid).first;
        missing = ApplySubmapUpdate(update, &it->second);
      });
  const IngestSummary summary = stack.Play("none");
  EXPECT_EQ(summary.frames_published, 60);
  EXPECT_EQ(summary.frames_unacked, 0);
  // Every keyframe the tracker made reached the mapper and was mapped.
  EXPECT_GT(stack.tracker.keyframes_published(), 3);
  EXPECT_EQ(stack.mapper->keyframes_mapped(), stack.tracker.keyframes_published());
  // The submap arrived whole and closed, with the mapper's final keyframe poses.
  ASSERT_EQ(replicas.size(), 1u);
  const SubmapReplica& replica = replicas.begin()->second;
  EXPECT_TRUE(replica.closed);
  EXPECT_TRUE(missing.empty());
  EXPECT_GT(replica.map.num_points(), 500u);
  ExpectReplicaIsTheMappersSubmap(replica, dir / "keyframes.tsv");
  // The tracker's poses follow the ground truth.
  EvaluationInput input;
  input.frames_total = 60;
  for (const auto& r : ReadFrameRecords(dir / "frames.tsv")) {
    if (r.state != "OK") continue;
    PoseRecord p;
    p.frame_index = r.frame_index;
    p.t_ns = r.t_ns;
    p.submap_id = r.submap_id;
    p.component = 0;
    p.world_from_cam = r.world_from_cam;
    input.poses.push_back(p);
  }
  input.ground_truth = stack.ground_truth;
  const Evaluation e = Evaluate(input);
  EXPECT_GE(e.frames_localized, 56);
  ASSERT_TRUE(e.errors);
  EXPECT_LT(e.errors->ate_rmse_m, 0.3);
}

// The tracker sends a keyframe again when the mapper is slow to answer it (a loaded machine: CI
// with two busy loops beside the run), and a lossy link repeats messages. Such a copy landing
// in the mapper's queue while the keyframe is being mapped cut its adjustment short as if a new
// keyframe waited, so a lockstep run's final poses depended on the machine's load. Every
// keyframe here arrives twice in a row: the mapper ends with the same keyframes at the same
// poses as without the copies, and no adjustment was cut short.
TEST(ServicesInProcess, AKeyframeSentTwiceDoesNotCutItsOwnAdjustmentShort) {
  struct Records {
    std::vector<std::string> frames, keyframes;  // frames.tsv without its timing column; keyframes.tsv
  };
  const auto fly = [](bool send_twice, int64_t* hurried) {
    testing::TempDir dir;
    // The copies are the test's own: the tracker waits for its mapper however slow the build
    // (under ThreadSanitizer a keyframe's adjustment takes seconds; after mapper_timeout_s / 2
    // the tracker would send copies of its own, and after mapper_timeout_s track on without it).
    InProcessStack stack([](StitchConfig* c) { c->tracker.mapper_timeout_s = 3600; }, /*with_mapper=*/true,
                         dir.path().string());
    bus::Subscriber echo(stack.lcm.get());
    std::set<int64_t> echoed;
    if (send_twice) {
      // Sent again by the tracker's own publisher (its session), as the tracker does.
      echo.Subscribe<stitch::keyframe_t>(
          bus::Channel("uav0", bus::kKeyframe), [&](std::unique_ptr<stitch::keyframe_t> keyframe, const std::string&) {
            if (echoed.insert(keyframe->keyframe_id).second)
              stack.publisher.Publish(bus::Channel("uav0", bus::kKeyframe), keyframe.get());
          });
    }
    stack.Play("30:6");
    *hurried = stack.mapper->keyframes_hurried();
    if (send_twice) {
      EXPECT_EQ(static_cast<int64_t>(echoed.size()), stack.tracker.keyframes_published());
    }
    Records records;
    for (FrameRecord r : ReadFrameRecords(dir / "frames.tsv")) {
      r.tracking_ms = 0;
      records.frames.push_back(FormatFrameRecord(r));
    }
    for (const KeyframeRecord& k : ReadKeyframeRecords(dir / "keyframes.tsv"))
      records.keyframes.push_back(FormatKeyframeRecord(k));
    std::sort(records.keyframes.begin(), records.keyframes.end());
    return records;
  };
  int64_t hurried_once = -1, hurried_twice = -1;
  const Records once = fly(false, &hurried_once);
  const Records twice = fly(true, &hurried_twice);
  ASSERT_GT(once.keyframes.size(), 10u);
  EXPECT_EQ(hurried_once, 0) << "lockstep: no keyframe waits behind another";
  EXPECT_EQ(hurried_twice, 0) << "a copy of a keyframe the mapper holds is only answered";
  EXPECT_EQ(once.frames, twice.frames) << "every frame's state, pose, points and keyframe";
  EXPECT_EQ(once.keyframes, twice.keyframes) << "the mapper's final keyframe poses";
}

// Keyframes are sent from a thread of their own; a frame's ack waits behind them, so a tracker
// killed between the two gets the frame again rather than losing a keyframe. memq:// delivers
// in the order messages were sent. With `send_frames_again`, every frame is sent again as soon
// as its status says it was tracked (the ingest's re-send when an ack is late, as on a slow
// machine): the ack of the re-send waits behind the keyframes too.
void ExpectAcksBehindTheirKeyframes(bool send_frames_again) {
  InProcessStack stack(nullptr, /*with_mapper=*/true, "");
  ASSERT_TRUE(stack.config.tracker.tracking.keyframe_worker);
  std::mutex mutex;
  std::set<int> acked;
  std::vector<int> acked_before_their_keyframe;
  std::set<int64_t> sent;
  std::map<int, stitch::frame_t> frames;  // as the ingest sent them, to send again
  int sent_again = 0;
  bus::Subscriber observer(stack.lcm.get());
  observer.Subscribe<stitch::frame_ack_t>(bus::Channel("uav0", bus::kFrameAck),
                                          [&](std::unique_ptr<stitch::frame_ack_t> ack, const std::string&) {
                                            std::lock_guard<std::mutex> lock(mutex);
                                            acked.insert(ack->frame_index);
                                          });
  observer.Subscribe<stitch::keyframe_t>(bus::Channel("uav0", bus::kKeyframe),
                                         [&](std::unique_ptr<stitch::keyframe_t> keyframe, const std::string&) {
                                           std::lock_guard<std::mutex> lock(mutex);
                                           if (!sent.insert(keyframe->keyframe_id).second)
                                             return;  // sent again (no answer from the mapper)
                                           // The first is the initialization's reference frame, made when a later frame
                                           // initialized; every other keyframe is the frame that made it.
                                           if (sent.size() > 1 && acked.count(keyframe->frame_index)) {
                                             acked_before_their_keyframe.push_back(keyframe->frame_index);
                                           }
                                         });
  if (send_frames_again) {
    observer.Subscribe<stitch::frame_t>(bus::Channel("uav0", bus::kFrame),
                                        [&](std::unique_ptr<stitch::frame_t> frame, const std::string&) {
                                          std::lock_guard<std::mutex> lock(mutex);
                                          frames.try_emplace(frame->frame_index, *frame);
                                        });
    observer.Subscribe<stitch::tracking_status_t>(
        bus::Channel("uav0", bus::kTrackingStatus),
        [&](std::unique_ptr<stitch::tracking_status_t> status, const std::string&) {
          std::lock_guard<std::mutex> lock(mutex);
          auto it = frames.find(status->frame_index);
          if (it == frames.end()) return;
          stack.publisher.Publish(bus::Channel("uav0", bus::kFrame), &it->second);
          frames.erase(it);  // once
          ++sent_again;
        });
  }
  stack.Play("none", 30);
  EXPECT_GE(sent.size(), 5u);
  EXPECT_EQ(acked.size(), 30u);
  if (send_frames_again) {
    EXPECT_GE(sent_again, 20);
  }
  EXPECT_TRUE(acked_before_their_keyframe.empty())
      << "frames acknowledged before their keyframe: " << ::testing::PrintToString(acked_before_their_keyframe);
}

TEST(ServicesInProcess, AFramesAckComesAfterTheKeyframesItMade) {
  ExpectAcksBehindTheirKeyframes(/*send_frames_again=*/false);
}

TEST(ServicesInProcess, AFrameSentAgainOnceTrackedIsAcknowledgedBehindItsKeyframes) {
  ExpectAcksBehindTheirKeyframes(/*send_frames_again=*/true);
}

// What the merger receives from a flight: the bytes on SUBMAP, and every submap rebuilt.
struct MergerSide {
  MergerSide(lcm::LCM* lcm, const ScalePyramid& pyramid, std::optional<bus::BusAuthenticator> authenticator = {})
      : pyramid(pyramid), subscriber(lcm, std::move(authenticator)) {
    subscriber.Subscribe<stitch::submap_update_t>(
        bus::Channel("uav0", bus::kSubmap),
        [this](std::unique_ptr<stitch::submap_update_t> message, const std::string&) {
          bytes += message->getEncodedSize();
          bytes_besides_keyframes += message->getEncodedSize();
          for (const stitch::keyframe_t& keyframe : message->keyframes)
            bytes_besides_keyframes -= keyframe._getEncodedSizeNoHash();
          const SubmapUpdate update = FromMessage(*message, this->pyramid);
          auto it = replicas.try_emplace(update.submap, update.submap, this->pyramid).first;
          if (!update.closed) {
            for (const MapPoint& point : update.changes.points)
              points_sent_again += it->second.map.FindPoint(point.id) != nullptr;
          }
          ApplySubmapUpdate(update, &it->second);
        });
  }
  ScalePyramid pyramid;
  bus::Subscriber subscriber;
  int64_t bytes = 0;
  int64_t bytes_besides_keyframes = 0;  // points, poses, associations: what thinning can leave out
  int64_t points_sent_again = 0;        // before the final (closed) state: refinements of points sent before
  std::map<SubmapId, SubmapReplica> replicas;
};

struct SubmapBytes {
  int64_t all = 0;
  int64_t besides_keyframes = 0;  // MergerSide::bytes_besides_keyframes
  int64_t points_sent_again = 0;  // MergerSide::points_sent_again
};

// Flies the default short flight; returns the SUBMAP bytes the merger side received. `thin`:
// the default thinning; `link_backlog_s` > 0: a link bridge reports that backlog all along.
// `keyed_bus`: the services' bus has a key (bus.key_file) that the reporting bridge lacks.
SubmapBytes FlyAndCountSubmapBytes(bool thin, double link_backlog_s = 0, bool keyed_bus = false) {
  testing::TempDir dir;
  if (keyed_bus) GenerateSecretFile(dir / "bus.key", "bus key");
  InProcessStack stack(
      [&](StitchConfig* c) {
        c->mapper.delivery.submap_point_resend_fraction = thin ? 0.01 : 0.0;
        c->mapper.delivery.submap_window_associations = !thin;
        c->mapper.delivery.stop_link_drain_s = 0;  // the reported backlog never goes out here
        if (keyed_bus) c->bus.key_file = dir / "bus.key";
      },
      /*with_mapper=*/true, dir.path().string());
  MergerSide merger(stack.lcm.get(), ScalePyramid::From(stack.config.tracker.tracking.orb),
                    stack.publisher.authenticator());
  std::atomic<bool> flying{true};
  std::thread bridge([&] {
    bus::Publisher publisher(stack.lcm.get(), "uav0");
    while (link_backlog_s > 0 && flying.load()) {
      stitch::link_status_t status{};
      status.budget_bytes_per_s = 100000;
      status.backlog_s = link_backlog_s;
      publisher.Publish(bus::Channel("uav0", bus::kLinkStatus), &status);
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
  });
  stack.Play("none");
  flying = false;
  bridge.join();
  EXPECT_EQ(merger.replicas.size(), 1u);
  if (merger.replicas.size() == 1) {
    EXPECT_TRUE(merger.replicas.begin()->second.closed);
    // The final state brings the replica to the mapper's submap whatever was left out before.
    ExpectReplicaIsTheMappersSubmap(merger.replicas.begin()->second, dir / "keyframes.tsv");
  }
  return {merger.bytes, merger.bytes_besides_keyframes, merger.points_sent_again};
}

TEST(ServicesInProcess, ThinnedSubmapUpdatesCostLessAndStillEndInTheMappersExactSubmap) {
  const int64_t full_bytes = FlyAndCountSubmapBytes(false).all, thin_bytes = FlyAndCountSubmapBytes(true).all;
  std::printf("SUBMAP bytes: %lld with every refinement, %lld thinned\n", static_cast<long long>(full_bytes),
              static_cast<long long>(thin_bytes));
  EXPECT_LT(thin_bytes, full_bytes * 6 / 10);
}

// The final state carries every point whatever was held back, so only what came before it shows
// the refinements held back.
TEST(ServicesInProcess, WhileTheLinkIsBehindTheMapperHoldsRefinementsBackAndTheFinalStateCatchesUp) {
  const SubmapBytes thin = FlyAndCountSubmapBytes(true), behind = FlyAndCountSubmapBytes(true, 10);
  std::printf(
      "SUBMAP bytes, besides keyframes (points sent again before the final state): %lld, %lld (%lld) thinned, "
      "%lld, %lld (%lld) with the link behind\n",
      static_cast<long long>(thin.all), static_cast<long long>(thin.besides_keyframes),
      static_cast<long long>(thin.points_sent_again), static_cast<long long>(behind.all),
      static_cast<long long>(behind.besides_keyframes), static_cast<long long>(behind.points_sent_again));
  // Not the keyframes' bytes: how many keyframes a flight makes follows its timing (under
  // ThreadSanitizer the run behind the link once made a few more, 1.81 MB in all against 1.75).
  EXPECT_LT(behind.besides_keyframes, thin.besides_keyframes);
  EXPECT_LT(behind.points_sent_again, thin.points_sent_again / 4);
}

// The security issue's row: a forged LINK_STATUS saying the link was 1e9 s behind made the mapper
// hold every refinement back (and the merged map 7 m off). A backlog beyond a day is refused.
TEST(ServicesInProcess, AnImplausibleLinkBacklogIsRefused) {
  const SubmapBytes forged = FlyAndCountSubmapBytes(true, 1e9);
  EXPECT_GT(forged.points_sent_again, 500);  // as without a bridge (2288 here); 0 when believed
}

// A plausible forged backlog (10 s, which the test above shows the mapper believes from a bridge)
// from a process without the bus's key: on a keyed bus (bus.key_file) it is refused, and the
// refinements go out as without a bridge. Unkeyed, the same process holds them back.
TEST(ServicesInProcess, OnAKeyedBusAForgedLinkBacklogIsRefused) {
  const SubmapBytes forged = FlyAndCountSubmapBytes(true, 10, /*keyed_bus=*/true);
  EXPECT_GT(forged.points_sent_again, 500);  // believed: about 0
  EXPECT_GT(forged.all, 0);                  // the keyed services heard each other
}

TEST(ServicesInProcess, TrackerWithoutAMapperKeepsTrackingAndSaysSo) {
  InProcessStack stack([](StitchConfig* c) { c->tracker.mapper_timeout_s = 0.4; }, /*with_mapper=*/false, "");
  const TrackingStatuses published(stack.lcm.get());
  const IngestSummary summary = stack.Play("none", 25);
  EXPECT_EQ(summary.frames_unacked, 0);
  const std::vector<stitch::tracking_status_t> statuses = published.Get();
  ASSERT_EQ(statuses.size(), 25u);
  // Tracked on its own initial map, reporting the mapper as absent after the first wait.
  int ok = 0;
  for (const auto& s : statuses) ok += s.state == stitch::tracking_status_t::STATE_OK;
  EXPECT_GT(ok, 15);
  EXPECT_FALSE(statuses.back().mapper_connected);
  EXPECT_EQ(stack.tracker.mapper_waits(), 1);  // lockstep frames wait, once: then it is absent
}

// Lockstep frames wait for a mapper that says it is running (its heartbeat) however long its
// answer takes: giving up after mapper_timeout_s made a run on a starved machine (or under a
// sanitizer) another run. Here the "mapper" only beats, until 3.5 mapper_timeout_s after the
// tracker began to wait, and never answers: the tracker holds the frame after its first keyframe
// while it beats, and reports the mapper absent only once the beats have stopped for
// mapper_timeout_s.
TEST(ServicesInProcess, LockstepFramesWaitForAMapperWhoseHeartbeatSaysItIsRunning) {
  constexpr double kTimeout = 1.0;
  InProcessStack stack([](StitchConfig* c) { c->tracker.mapper_timeout_s = kTimeout; }, /*with_mapper=*/false, "");
  std::atomic<bool> beating{true};
  std::vector<bool> received_while_beating;  // under the statuses' lock
  const TrackingStatuses published(
      stack.lcm.get(), [&](const stitch::tracking_status_t&) { received_while_beating.push_back(beating); });
  std::thread mapper([&] {
    stitch::service_status_t beat;
    beat.service = "mapper";
    beat.state = stitch::service_status_t::STATE_RUNNING;
    std::optional<std::chrono::steady_clock::time_point> until;
    const auto give_up = std::chrono::steady_clock::now() + std::chrono::minutes(5);
    while (!until || std::chrono::steady_clock::now() < *until) {
      if (!until && (stack.tracker.mapper_waits() > 0 || std::chrono::steady_clock::now() > give_up))
        until = std::chrono::steady_clock::now() + std::chrono::milliseconds(static_cast<int>(3500 * kTimeout));
      stack.publisher.Publish(bus::Channel("uav0", bus::kService), &beat);
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    beating = false;
  });
  const IngestSummary summary = stack.Play("none", 25);
  mapper.join();
  EXPECT_EQ(summary.frames_unacked, 0);
  const std::vector<stitch::tracking_status_t> statuses = published.Get();
  ASSERT_EQ(statuses.size(), 25u);
  ASSERT_EQ(received_while_beating.size(), 25u);
  EXPECT_EQ(stack.tracker.mapper_waits(), 1);
  int while_beating = 0;
  for (size_t i = 0; i < statuses.size(); ++i) {
    if (!received_while_beating[i]) continue;
    ++while_beating;
    EXPECT_TRUE(statuses[i].mapper_connected) << "frame " << statuses[i].frame_index << ": gave up while it beat";
  }
  EXPECT_GT(while_beating, 0);   // the frames up to the first keyframe
  EXPECT_LT(while_beating, 25);  // the rest waited for the beats to stop
  EXPECT_FALSE(statuses.back().mapper_connected);
}

// Frames from a live source never wait for the mapper: with none answering, the tracker takes
// every frame as it comes (how many it drops depends on the machine: a sanitizer build on a
// loaded one drops most), reports the mapper absent once its keyframes went unanswered for
// mapper_timeout_s, and goes on making keyframes. Lockstep frames wait (the test above). On a
// thin map a live tracker waits a moment for a keyframe's points (live_wait_for_points_s), at
// most once per keyframe, and not at all once the mapper is reported absent.
TEST(ServicesInProcess, LiveFramesNeverWaitForTheMapper) {
  InProcessStack stack(
      [](StitchConfig* c) {
        c->tracker.mapper_timeout_s = 2.0;
        c->ingest.pacing = "realtime";
        c->ingest.speed = 0.25;  // 5 frames a second
      },
      /*with_mapper=*/false, "");
  const TrackingStatuses published(stack.lcm.get());
  stack.Play("none", 30);
  EXPECT_EQ(stack.tracker.mapper_waits(), 0);
  const std::vector<stitch::tracking_status_t> statuses = published.Get();
  ASSERT_FALSE(statuses.empty());
  EXPECT_FALSE(statuses.back().mapper_connected);
  EXPECT_GT(stack.tracker.keyframes_published(), 2);  // more than initialization's two
  EXPECT_LE(stack.tracker.points_waits(), stack.tracker.keyframes_published());
}

// A live camera's 60 frames published in one burst: the tracker drops most for newer ones. Each
// frame still has one line in frames.tsv, in frame order (a dropped frame's line was written by
// the bus's thread, before the line of the older frame the tracker was still tracking).
TEST(ServicesInProcess, FramesDroppedForNewerOnesAreRecordedInFrameOrder) {
  testing::TempDir dir;
  InProcessStack stack(nullptr, /*with_mapper=*/false, dir.path().string());
  SourceSpec spec;
  spec.synthetic = stack.config.synthetic;
  spec.failures = "none";
  FailureSchedule unused;
  auto sequence = OpenSource(spec, &unused);
  std::vector<stitch::frame_t> frames;
  SequenceFrame frame;
  while (sequence->Next(&frame)) {
    stitch::frame_t message{};
    message.camera = ToMessage(sequence->camera());
    message.pacing = stitch::frame_t::PACING_LIVE;
    message.frame_index = frame.index;
    message.t_ns = frame.t_ns;
    EncodeImage(frame.image, ImageEncoding::kGray8, 90, &message);
    frames.push_back(std::move(message));
  }
  ASSERT_EQ(frames.size(), 60u);
  {
    bus::Dispatcher dispatcher(stack.lcm.get());
    dispatcher.Start();
    stack.tracker.Start();
    for (stitch::frame_t& message : frames) stack.publisher.Publish(bus::Channel("uav0", bus::kFrame), &message);
    stack.WaitUntilDispatched();
    stack.tracker.Stop();
    dispatcher.Stop();
  }
  const std::vector<FrameRecord> records = ReadFrameRecords(dir / "frames.tsv");
  ASSERT_EQ(records.size(), 60u);
  int dropped = 0;
  for (size_t i = 0; i < records.size(); ++i) {
    EXPECT_EQ(records[i].frame_index, static_cast<int>(i));
    dropped += records[i].reason == static_cast<int>(TrackingReason::kDropped);
  }
  EXPECT_GT(dropped, 5);
}

TEST(ServicesInProcess, ALossClosesTheSubmapForTheMergerBeforeTheNextOneStarts) {
  InProcessStack stack(nullptr, /*with_mapper=*/true, "");
  std::vector<std::pair<SubmapId, bool>> events;  // (submap, closed) per update, in arrival order
  int first_closed_before_status = -1;            // frame of the last status before submap 1 closed
  int last_status_frame = -1;
  bus::Subscriber merger_side(stack.lcm.get());
  merger_side.Subscribe<stitch::submap_update_t>(
      bus::Channel("uav0", bus::kSubmap), [&](std::unique_ptr<stitch::submap_update_t> message, const std::string&) {
        events.push_back({SubmapId(message->submap_id), message->closed});
        if (message->closed && first_closed_before_status < 0) first_closed_before_status = last_status_frame;
      });
  merger_side.Subscribe<stitch::tracking_status_t>(
      bus::Channel("uav0", bus::kTrackingStatus), [&](std::unique_ptr<stitch::tracking_status_t> status,
                                                      const std::string&) { last_status_frame = status->frame_index; });
  stack.Play("30:6");
  // Submap 1's final state (closed) arrives before anything of submap 2.
  const SubmapId first = MakeSubmapId(0, 1), second = MakeSubmapId(0, 2);
  int first_closed_at = -1, second_starts_at = -1;
  for (size_t i = 0; i < events.size(); ++i) {
    if (events[i].first == first && events[i].second && first_closed_at < 0) first_closed_at = static_cast<int>(i);
    if (events[i].first == second && second_starts_at < 0) second_starts_at = static_cast<int>(i);
  }
  ASSERT_GE(first_closed_at, 0);
  ASSERT_GE(second_starts_at, 0) << "a new submap after the loss";
  EXPECT_LT(first_closed_at, second_starts_at);
  // Closed when the tracker reported the loss (frame 32, the third blurred frame), not later
  // when submap 2 began (frame 37).
  EXPECT_GE(first_closed_before_status, 32);
  EXPECT_LT(first_closed_before_status, 36);
  EXPECT_TRUE(events.back().second) << "the last submap is closed at shutdown";
}

// What a 100 kB/s link bridge and a merger tell the mapper in the tests below: how far behind the
// bridge is (nothing when negative) and which keyframe the merger asks for (none when invalid).
void SayToTheMapper(bus::Publisher* publisher, double link_backlog_s, KeyframeId wanted) {
  if (link_backlog_s >= 0) {
    stitch::link_status_t status{};
    status.budget_bytes_per_s = 100000;
    status.backlog_s = link_backlog_s;
    publisher->Publish(bus::Channel("uav0", bus::kLinkStatus), &status);
  }
  if (wanted.valid()) {
    stitch::submap_request_t request{};
    request.submap_id = SubmapOf(wanted).value;
    request.num_keyframes = 1;
    request.keyframe_ids = {wanted.value};
    publisher->Publish(bus::Channel("uav0", bus::kSubmapRequest), &request);
  }
}

// Memory over a long flight: submaps hand over at a keyframe cap; the mapper lets go of a closed
// submap only once the merger says it holds it whole and the tracker has dropped it, and its
// records still hold every submap's keyframes and points.
// A 474-frame flight behind a 100 kB/s link (the merge campaign's flight-026): the merger asked
// for the keyframes it lacked while they still waited in the bridge's queue, and the mapper
// queued them again at every request, once every half second: 610 keyframes sent again, the
// flight's bytes tripled. A ground that keeps asking for one keyframe of the first submap through
// a 20-frame flight and the mapper's 2 s linger after it: how many times it is sent, with the
// bridge reporting `link_backlog_s` all along (0: no bridge).
int TimesAKeyframeIsSentWhileTheMergerKeepsAskingForIt(double link_backlog_s) {
  InProcessStack stack(
      [](StitchConfig* c) {
        c->mapper.delivery.stop_linger_s = 2;
        c->mapper.delivery.stop_link_drain_s = 0;     // the reported backlog never goes out here
        c->mapper.delivery.resend_max_hold_s = 3600;  // longer than the flight takes under any sanitizer
        c->mapper.delivery.link_backlog_defer_s = 0;  // answered behind any backlog (the test below waits)
      },
      /*with_mapper=*/true, "");
  const KeyframeId wanted = MakeKeyframeId(MakeSubmapId(0, 1), 1);
  std::atomic<int> sent{0};
  bus::Subscriber merger_side(stack.lcm.get());
  merger_side.Subscribe<stitch::submap_update_t>(
      bus::Channel("uav0", bus::kSubmap), [&](std::unique_ptr<stitch::submap_update_t> message, const std::string&) {
        for (const stitch::keyframe_t& keyframe : message->keyframes)
          sent += KeyframeId(keyframe.keyframe_id) == wanted;
      });
  std::atomic<bool> flying{true};
  std::thread ground([&] {
    bus::Publisher publisher(stack.lcm.get(), "uav0");
    while (flying.load()) {
      SayToTheMapper(&publisher, link_backlog_s > 0 ? link_backlog_s : -1, sent.load() > 0 ? wanted : KeyframeId());
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
  });
  stack.Play("none", 20);
  flying = false;
  ground.join();
  return sent.load();
}

TEST(ServicesInProcess, BehindALinkTheMapperSendsAKeyframeAgainOnlyOnceTheBacklogHadTimeToGoOut) {
  const int without_link = TimesAKeyframeIsSentWhileTheMergerKeepsAskingForIt(0);
  const int behind = TimesAKeyframeIsSentWhileTheMergerKeepsAskingForIt(1000);
  std::printf("the keyframe asked for was sent %d times without a link, %d behind a 1000 s backlog\n", without_link,
              behind);
  EXPECT_GE(without_link, 3) << "answered every half second";
  EXPECT_EQ(behind, 1) << "the first sending is still on its way";
}

// Behind a link bridge more than mapper.link_backlog_defer_s behind, what the mapper queues there
// would wait until it expires: new keyframes stay on the aircraft (the manifests list them) and
// the merger's requests wait until the backlog falls, here when the flight has ended.
struct DeferredFlight {
  int keyframes_in_flight = 0;  // keyframes the mapper sent before the flight's final state
  bool wanted_in_a_manifest = false;
  int wanted_sent_after = 0;  // the keyframe asked for, sent once the backlog had fallen
};

DeferredFlight FlyBehindALinkThatFallsBehind(double defer_s) {
  InProcessStack stack(
      [defer_s](StitchConfig* c) {
        c->mapper.delivery.stop_linger_s = 2;
        c->mapper.delivery.stop_link_drain_s = 0;
        c->mapper.delivery.link_backlog_defer_s = defer_s;
      },
      /*with_mapper=*/true, "");
  const KeyframeId wanted = MakeKeyframeId(MakeSubmapId(0, 1), 3);
  std::mutex mutex;
  DeferredFlight flight;
  std::atomic<bool> landed{false}, flying{true};
  bus::Subscriber merger_side(stack.lcm.get());
  merger_side.Subscribe<stitch::submap_update_t>(
      bus::Channel("uav0", bus::kSubmap), [&](std::unique_ptr<stitch::submap_update_t> message, const std::string&) {
        std::lock_guard<std::mutex> lock(mutex);
        if (message->closed && message->full_state) landed = true;
        for (const stitch::keyframe_t& keyframe : message->keyframes) {
          if (!landed) ++flight.keyframes_in_flight;
          if (landed && KeyframeId(keyframe.keyframe_id) == wanted) ++flight.wanted_sent_after;
        }
        for (int64_t id : message->manifest_keyframe_ids) flight.wanted_in_a_manifest |= KeyframeId(id) == wanted;
      });
  std::thread ground([&] {
    bus::Publisher publisher(stack.lcm.get(), "uav0");
    while (flying.load()) {
      SayToTheMapper(&publisher, landed ? 0 : 30, wanted);  // the link catches up once the aircraft has landed
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
  });
  stack.Play("none", 20);
  flying = false;
  ground.join();
  std::lock_guard<std::mutex> lock(mutex);
  return flight;
}

TEST(ServicesInProcess, FarBehindALinkTheMapperKeepsKeyframesUntilAskedOnceTheBacklogFalls) {
  const DeferredFlight deferred = FlyBehindALinkThatFallsBehind(20), sent = FlyBehindALinkThatFallsBehind(0);
  std::printf("keyframes sent during the flight: %d behind a 30 s backlog, %d when not waiting for it\n",
              deferred.keyframes_in_flight, sent.keyframes_in_flight);
  EXPECT_GT(sent.keyframes_in_flight, 4);
  EXPECT_LE(deferred.keyframes_in_flight, 2) << "only what went before the bridge's first report";
  EXPECT_TRUE(deferred.wanted_in_a_manifest) << "the merger learns that the keyframe exists";
  EXPECT_GE(deferred.wanted_sent_after, 1) << "and gets it once the link has caught up";
}

TEST(ServicesInProcess, TheMapperLetsGoOfASubmapOnlyOnceTheMergerHoldsItWholeAndTheTrackerDroppedIt) {
  stitch::testing::TempDir dir;
  InProcessStack stack(
      [](StitchConfig* c) {
        c->synthetic.flight.num_frames = 100;
        c->synthetic.flight.strip_length_m = 115;
        c->tracker.tracking.submap_max_keyframes = 10;
        c->tracker.tracking.handover_keyframes = 3;
        c->tracker.tracking.closed_keyframes_held = 0;
        c->mapper.delivery.stop_linger_s = 1;  // submap 2 is never confirmed: the stop need not wait 10 s for it
      },
      /*with_mapper=*/true, dir.path().string());
  // A merger that says it holds every submap whole but submap 2.
  bus::Publisher ground(stack.lcm.get(), "uav0");
  std::set<SubmapId> closed;
  bus::Subscriber merger_side(stack.lcm.get());
  merger_side.Subscribe<stitch::submap_update_t>(
      bus::Channel("uav0", bus::kSubmap), [&](std::unique_ptr<stitch::submap_update_t> message, const std::string&) {
        if (!message->closed) return;
        closed.insert(SubmapId(message->submap_id));
        if (SubmapId(message->submap_id) == MakeSubmapId(0, 2)) return;
        stitch::submap_request_t confirmation{};
        confirmation.submap_id = message->submap_id;
        confirmation.complete = true;
        ground.Publish(bus::Channel("uav0", bus::kSubmapRequest), &confirmation);
      });
  stack.Play("none");
  ASSERT_GE(closed.size(), 3u) << "two handovers";
  // Every submap but two: submap 2 (the tracker dropped it too, but the merger never confirmed
  // it) and the last (the tracker held it to the end).
  EXPECT_EQ(stack.mapper->submaps_released(), static_cast<int>(closed.size()) - 2);
  std::map<SubmapId, int> keyframes;
  for (const KeyframeRecord& k : ReadKeyframeRecords(dir / "keyframes.tsv")) ++keyframes[SubmapId(k.submap_id)];
  for (SubmapId submap : closed) EXPECT_GE(keyframes[submap], 3) << SubmapName(submap);
  EXPECT_GE(keyframes[MakeSubmapId(0, 1)], 10) << "the submap let go keeps its keyframes in keyframes.tsv";
  EXPECT_FALSE(std::filesystem::exists(dir / ".released_points.bin"));
  EXPECT_GT(ReadPly(dir / "submaps.ply").size(), 3000u);
}

// Plays the short flight with nothing failing and, once the tracker has reported frame 30,
// publishes `statuses` with `publisher`; returns how many submaps the mapper closed before the
// last frame's status (the flight's one submap closes at shutdown).
int SubmapsClosedDuringTheFlight(InProcessStack* stack, bus::Publisher* publisher,
                                 const std::vector<stitch::tracking_status_t>& statuses) {
  std::mutex mutex;
  int last_status_frame = -1, closed_during_flight = 0;
  bus::Subscriber merger_side(stack->lcm.get());
  merger_side.Subscribe<stitch::submap_update_t>(
      bus::Channel("uav0", bus::kSubmap), [&](std::unique_ptr<stitch::submap_update_t> message, const std::string&) {
        std::lock_guard<std::mutex> lock(mutex);
        if (message->closed && last_status_frame < 59) ++closed_during_flight;
      });
  merger_side.Subscribe<stitch::tracking_status_t>(
      bus::Channel("uav0", bus::kTrackingStatus),
      [&](std::unique_ptr<stitch::tracking_status_t> status, const std::string&) {
        std::lock_guard<std::mutex> lock(mutex);
        last_status_frame = std::max(last_status_frame, status->frame_index);
      });
  std::atomic<bool> flying{true};
  std::thread sender([&] {
    for (bool sent = false; flying.load() && !sent; std::this_thread::sleep_for(std::chrono::milliseconds(5))) {
      {
        std::lock_guard<std::mutex> lock(mutex);
        if (last_status_frame < 30) continue;
      }
      for (stitch::tracking_status_t status : statuses)
        publisher->Publish(bus::Channel("uav0", bus::kTrackingStatus), &status);
      sent = true;
    }
  });
  stack->Play("none");
  flying = false;
  sender.join();
  std::lock_guard<std::mutex> lock(mutex);
  EXPECT_EQ(last_status_frame, 59);
  return closed_during_flight;
}

// A status at frame 31 in submap 1 that counts `submaps_closed` closures.
stitch::tracking_status_t StatusAtFrame31(int8_t state, int submaps_closed) {
  stitch::tracking_status_t status{};
  status.frame_index = 31;
  status.state = state;
  status.submap_id = MakeSubmapId(0, 1).value;
  status.submaps_closed = submaps_closed;
  return status;
}

// The tracker's status that says it closed a submap (on a loss) can be lost on the way; the next
// one that arrives counts the closure but names the submap the tracker is in now. The mapper
// closed that one, the submap being tracked, and sent the merger its "final" state mid-flight.
// Here the tracker's own publisher tells of a closure at frame 31 while it tracks on in submap 1.
TEST(ServicesInProcess, ALateClosingStatusDoesNotCloseTheSubmapBeingTracked) {
  InProcessStack stack(nullptr, /*with_mapper=*/true, "");
  EXPECT_EQ(
      SubmapsClosedDuringTheFlight(&stack, &stack.publisher, {StatusAtFrame31(stitch::tracking_status_t::STATE_OK, 1)}),
      0);
}

// The security issue's row "closing statuses only from the tracker's session": two statuses from
// another session in mid-flight (the first set the count the mapper compared with, the second
// said one more submap had closed) made the mapper close the submap the tracker was still
// mapping. They are refused; the submap closes only at shutdown.
TEST(ServicesInProcess, AClosingStatusFromAnotherSessionClosesNothing) {
  InProcessStack stack(nullptr, /*with_mapper=*/true, "");
  bus::Publisher stranger(stack.lcm.get(), "uav0");  // a session of its own
  EXPECT_EQ(SubmapsClosedDuringTheFlight(&stack, &stranger,
                                         {StatusAtFrame31(stitch::tracking_status_t::STATE_LOST, 0),
                                          StatusAtFrame31(stitch::tracking_status_t::STATE_LOST, 1)}),
            0);
}

}  // namespace
}  // namespace stitch
