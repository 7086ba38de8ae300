// Ingest, tracker and mapper services on one in-process bus (memq://), as in a single process.

#include <fstream>
#include <map>
#include <sstream>

#include <gtest/gtest.h>

#include "services/common/map_convert.h"
#include "services/config/stitch_config.h"
#include "services/ingest/ingest.h"
#include "services/mapper/mapper_service.h"
#include "services/tracker/tracker_service.h"
#include "stitch/eval/evaluation.h"
#include "stitch/eval/frame_record.h"
#include "stitch/source/source.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/tracking_status_t.hpp"

namespace stitch {
namespace {

TEST(ServicesInProcess, IngestTrackerAndMapperTrackAShortFlightOverMemq) {
  testing::TempDir dir;
  const StitchConfig config = LoadStitchConfig(std::string(STITCH_SOURCE_DIR) + "/tests/short_flight.yaml");
  const Vocabulary vocabulary = LoadVocabulary(config);
  auto lcm = bus::OpenLcm("memq://");
  bus::Publisher publisher(lcm.get(), "uav0");
  IngestService ingest(lcm.get(), "memq://", &publisher, config.ingest);
  TrackerService tracker(lcm.get(), &publisher, config.tracker, &vocabulary, dir / "frames.tsv");
  MapperService mapper(lcm.get(), &publisher, config.mapper, config.tracker.tracking.orb, &vocabulary, dir.path().string());
  // What a merger would receive: every submap rebuilt from the SUBMAP channel.
  const ScalePyramid pyramid = ScalePyramid::From(config.tracker.tracking.orb);
  std::map<SubmapId, SubmapReplica> replicas;
  std::vector<KeyframeId> missing;
  bus::Subscriber merger_side(lcm.get());
  merger_side.Subscribe<stitch::submap_update_t>(
      bus::Channel("uav0", bus::kSubmap), [&](std::unique_ptr<stitch::submap_update_t> message, const std::string&) {
        const SubmapUpdate update = FromMessage(*message, pyramid);
        auto it = replicas.try_emplace(update.submap, update.submap, pyramid).first;
        missing = ApplySubmapUpdate(update, &it->second);
      });
  bus::Dispatcher dispatcher(lcm.get());
  dispatcher.Start();
  mapper.Start();
  tracker.Start();
  SourceSpec spec;
  spec.synthetic = config.synthetic;
  spec.failures = "none";
  FailureSchedule spoil;
  auto sequence = OpenSource(spec, &spoil);
  std::atomic<bool> stop{false};
  const IngestSummary summary = ingest.Play(*sequence, spoil, stop);
  tracker.Stop();
  mapper.Stop();
  dispatcher.Stop();
  EXPECT_EQ(summary.frames_published, 60);
  EXPECT_EQ(summary.frames_unacked, 0);
  // Every keyframe the tracker made reached the mapper and was mapped.
  EXPECT_GT(tracker.keyframes_published(), 3);
  EXPECT_EQ(mapper.keyframes_mapped(), tracker.keyframes_published());
  // The submap arrived whole and closed, with the mapper's final keyframe poses.
  ASSERT_EQ(replicas.size(), 1u);
  const SubmapReplica& replica = replicas.begin()->second;
  EXPECT_TRUE(replica.closed);
  EXPECT_TRUE(missing.empty());
  EXPECT_GT(replica.map.num_points(), 500u);
  std::ifstream keyframes(dir / "keyframes.tsv");
  std::string line;
  int kept = 0;
  while (std::getline(keyframes, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream fields(line);
    int64_t id, submap, frame_index, t_ns;
    int culled;
    double tx, ty, tz;
    fields >> id >> submap >> frame_index >> t_ns >> culled >> tx >> ty >> tz;
    if (culled) continue;
    ++kept;
    const Keyframe* keyframe = replica.map.FindKeyframe(KeyframeId(id));
    ASSERT_NE(keyframe, nullptr) << id;
    EXPECT_LT((keyframe->Centre() - Eigen::Vector3d(tx, ty, tz)).norm(), 1e-4);
  }
  EXPECT_EQ(static_cast<size_t>(kept), replica.map.num_keyframes());
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
  input.ground_truth = sequence->ground_truth();
  const Evaluation e = Evaluate(input);
  EXPECT_GE(e.frames_localized, 56);
  ASSERT_TRUE(e.errors);
  EXPECT_LT(e.errors->ate_rmse_m, 0.3);
}

}  // namespace
}  // namespace stitch

namespace stitch {
namespace {

TEST(ServicesInProcess, TrackerWithoutAMapperKeepsTrackingAndSaysSo) {
  StitchConfig config = LoadStitchConfig(std::string(STITCH_SOURCE_DIR) + "/tests/short_flight.yaml");
  config.tracker.mapper_timeout_s = 0.4;
  const Vocabulary vocabulary = LoadVocabulary(config);
  auto lcm = bus::OpenLcm("memq://");
  bus::Publisher publisher(lcm.get(), "uav0");
  IngestService ingest(lcm.get(), "memq://", &publisher, config.ingest);
  TrackerService tracker(lcm.get(), &publisher, config.tracker, &vocabulary, "");
  std::mutex mutex;
  std::vector<stitch::tracking_status_t> statuses;
  bus::Subscriber subscriber(lcm.get());
  subscriber.Subscribe<stitch::tracking_status_t>(bus::Channel("uav0", bus::kTrackingStatus),
                                                  [&](std::unique_ptr<stitch::tracking_status_t> s, const std::string&) {
                                                    std::lock_guard<std::mutex> lock(mutex);
                                                    statuses.push_back(*s);
                                                  });
  bus::Dispatcher dispatcher(lcm.get());
  dispatcher.Start();
  tracker.Start();
  SourceSpec spec;
  spec.synthetic = config.synthetic;
  spec.failures = "none";
  spec.max_frames = 25;
  FailureSchedule spoil;
  auto sequence = OpenSource(spec, &spoil);
  std::atomic<bool> stop{false};
  const IngestSummary summary = ingest.Play(*sequence, spoil, stop);
  tracker.Stop();
  dispatcher.Stop();
  EXPECT_EQ(summary.frames_unacked, 0);
  std::lock_guard<std::mutex> lock(mutex);
  ASSERT_EQ(statuses.size(), 25u);
  // Tracked on its own initial map, reporting the mapper as absent after the first wait.
  int ok = 0;
  for (const auto& s : statuses) ok += s.state == stitch::tracking_status_t::STATE_OK;
  EXPECT_GT(ok, 15);
  EXPECT_FALSE(statuses.back().mapper_connected);
}

}  // namespace
}  // namespace stitch
