// The merger service on an in-process bus (memq://), fed what a mapper sends on <agent>/SUBMAP
// during the short flight, with hostile updates between the real ones.

#include <chrono>
#include <climits>
#include <cmath>
#include <mutex>
#include <optional>
#include <thread>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "services/common/convert.h"
#include "services/common/map_convert.h"
#include "services/merger/merger_service.h"
#include "stitch/config/stitch_config.h"
#include "stitch/map_cloud_t.hpp"
#include "stitch/pipeline/inline_pipeline.h"
#include "stitch/source/source.h"
#include "stitch/testing/temp_dir.h"
#include "tests/memq_dispatched.h"

namespace stitch {
namespace {

StitchConfig ShortFlight() {
  return LoadStitchConfig(std::string(STITCH_SOURCE_DIR) + "/tests/short_flight.yaml");
}

// What the mapper publishes on <agent>/SUBMAP while the flight is tracked (by default without a
// gust).
std::vector<stitch::submap_update_t> MappersUpdates(const StitchConfig& config, const Vocabulary& vocabulary,
                                                    const std::string& failures = "none") {
  SourceSpec spec;
  spec.synthetic = config.synthetic;
  spec.failures = failures;
  FailureSchedule unused;
  auto sequence = OpenSource(spec, &unused);
  return ToMessages(
      RunInline(*sequence, config.pipeline(), vocabulary, nullptr, /*keep_submap_updates=*/true).submap_updates);
}

// A merger on a memq bus; `Send` publishes as the aircraft uav0, `Finish` stops it once all that
// was sent is handled.
class MergerOnMemq {
 public:
  MergerOnMemq(const StitchConfig& config, const Vocabulary& vocabulary, const std::string& record_dir = "")
      : lcm_(bus::OpenLcm("memq://")),
        publisher_(lcm_.get(), "uav0"),
        merger_(lcm_.get(), &publisher_, config.merger, config.tracker.tracking.orb, &vocabulary, record_dir),
        dispatcher_(lcm_.get()) {
    dispatcher_.Start();
    merger_.Start();
  }
  lcm::LCM* lcm() { return lcm_.get(); }
  void Send(stitch::submap_update_t message) { publisher_.Publish(bus::Channel("uav0", bus::kSubmap), &message); }
  void Send(stitch::gnss_fix_t message) { publisher_.Publish(bus::Channel("uav0", bus::kGnss), &message); }
  void Send(stitch::keyframe_image_t message) {
    publisher_.Publish(bus::Channel("uav0", bus::kKeyframeImage), &message);
  }
  const Merger& Finish() {
    testing::WaitUntilDispatched(lcm_.get());
    merger_.Stop();
    dispatcher_.Stop();
    return merger_.merger();
  }

 private:
  std::unique_ptr<lcm::LCM> lcm_;
  bus::Publisher publisher_;
  MergerService merger_;
  bus::Dispatcher dispatcher_;
};

// The security issue's row "a submap state's revision may not jump arbitrarily": one forged
// full state numbered 2^31-1 (its points moved 5 m) in the middle of the flight made every later
// real update of the submap stale: the merger kept the forged points and never applied another.
TEST(MergerServiceInProcess, AForgedRevisionFarAheadIsRefusedAndTheRealUpdatesStillApply) {
  const StitchConfig config = ShortFlight();
  const Vocabulary vocabulary = LoadVocabulary(config);
  const std::vector<stitch::submap_update_t> updates = MappersUpdates(config, vocabulary);
  ASSERT_GT(updates.size(), 6u);

  // The submap as the real updates leave it.
  MergerOnMemq honest(config, vocabulary);
  for (const auto& update : updates) honest.Send(update);
  const Merger& expected = honest.Finish();
  ASSERT_EQ(expected.submaps().size(), 1u);
  const SubmapReplica& real = expected.submaps().begin()->second;

  MergerOnMemq attacked(config, vocabulary);
  const size_t half = updates.size() / 2;
  for (size_t i = 0; i < half; ++i) attacked.Send(updates[i]);
  stitch::submap_update_t forged = updates[half - 1];
  forged.revision = INT_MAX;
  forged.full_state = true;
  for (auto& point : forged.points) point.position[2] += 5;
  attacked.Send(forged);
  stitch::submap_update_t negative = updates[half - 1];
  negative.revision = -1;
  attacked.Send(negative);
  for (size_t i = half; i < updates.size(); ++i) attacked.Send(updates[i]);
  const Merger& merger = attacked.Finish();
  ASSERT_EQ(merger.submaps().size(), 1u);
  const SubmapReplica& replica = merger.submaps().begin()->second;

  EXPECT_EQ(replica.newest_revision, real.newest_revision);
  EXPECT_EQ(replica.full_state_revision, real.full_state_revision);
  EXPECT_EQ(replica.map.num_keyframes(), real.map.num_keyframes());
  ASSERT_EQ(replica.map.num_points(), real.map.num_points());
  for (const auto& [id, point] : real.map.points()) {
    const MapPoint* received = replica.map.FindPoint(id);
    ASSERT_NE(received, nullptr);
    EXPECT_LT((received->position - point.position).norm(), 1e-9) << id.value;
  }
}

// The live view's map follows the merger's as a submap grows, not only once it closes (#46: at
// frame 149 of TUM fr1/rpy the tracker had made 30 keyframes and the page showed no map): after
// the updates of a submap still being mapped, a cloud comes that holds every keyframe the merger
// took and their points.
TEST(MergerServiceInProcess, TheMapCloudFollowsAGrowingSubmap) {
  const StitchConfig config = ShortFlight();
  const Vocabulary vocabulary = LoadVocabulary(config);
  const std::vector<stitch::submap_update_t> updates = MappersUpdates(config, vocabulary);
  ASSERT_GT(updates.size(), 8u);
  MergerOnMemq merger(config, vocabulary);
  std::mutex mutex;
  std::vector<std::pair<int, int>> clouds;  // keyframes and points of the flight's submap
  bus::Subscriber subscriber(merger.lcm());
  subscriber.Subscribe<stitch::map_cloud_t>(bus::Channel("uav0", bus::kMapCloud),
                                            [&](std::unique_ptr<stitch::map_cloud_t> cloud, const std::string&) {
                                              std::lock_guard<std::mutex> lock(mutex);
                                              for (int s = 0; s < cloud->num_submaps; ++s) {
                                                if (cloud->submap_ids[s] == updates.front().submap_id) {
                                                  clouds.push_back({cloud->keyframe_counts[s], cloud->point_counts[s]});
                                                }
                                              }
                                            });
  // The cloud that holds `keyframes`, waited for (the merger makes it on its own thread).
  const auto cloud_with = [&](int keyframes) -> std::optional<std::pair<int, int>> {
    for (int wait = 0; wait < 200; ++wait) {
      testing::WaitUntilDispatched(merger.lcm());
      {
        std::lock_guard<std::mutex> lock(mutex);
        for (const auto& cloud : clouds) {
          if (cloud.first == keyframes) return cloud;
        }
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    return std::nullopt;
  };
  int held = 0, checked = 0;
  for (size_t i = 0; i < updates.size() && !updates[i].closed; ++i) {
    merger.Send(updates[i]);
    held += updates[i].num_keyframes - updates[i].num_removed_keyframes;
    if (i != updates.size() / 4 && i != updates.size() / 2) continue;
    const auto cloud = cloud_with(held);
    ASSERT_TRUE(cloud) << "no cloud of the " << held << " keyframes held after update " << i;
    EXPECT_GT(cloud->second, 10 * held) << "points of " << held << " keyframes";
    ++checked;
  }
  EXPECT_EQ(checked, 2);
  merger.Finish();
}

// The aircraft's GNSS fixes reach the ground's records (gnss_received.csv), each time once; a fix
// that is no place on Earth, or of a type no receiver has, is refused.
TEST(MergerServiceInProcess, KeepsTheAircraftsGnssFixesAndRefusesImpossibleOnes) {
  const StitchConfig config = ShortFlight();
  const Vocabulary vocabulary = LoadVocabulary(config);
  testing::TempDir dir;
  MergerOnMemq merger(config, vocabulary, dir.path().string());
  GnssFix fix;
  fix.position = {48.0, 11.0, 650.0};
  fix.horizontal_accuracy_m = 2;
  fix.vertical_accuracy_m = 3;
  for (int i = 0; i < 20; ++i) {
    fix.t_ns = i * 200'000'000LL;
    fix.position.latitude_deg = 48.0 + i * 1e-5;
    merger.Send(ToMessage(fix));
  }
  merger.Send(ToMessage(fix));  // the link repeats one
  stitch::gnss_fix_t nowhere = ToMessage(fix);
  nowhere.t_ns += 1;
  nowhere.latitude_deg = NAN;
  merger.Send(nowhere);
  stitch::gnss_fix_t unknown = ToMessage(fix);
  unknown.t_ns += 2;
  unknown.fix_type = 9;
  merger.Send(unknown);
  merger.Finish();
  const GnssTrack received = ReadGnssCsv(dir / "gnss_received.csv");
  ASSERT_EQ(received.fixes.size(), 20u);
  EXPECT_EQ(received.fixes[19].t_ns, 19 * 200'000'000LL);
  EXPECT_DOUBLE_EQ(received.fixes[19].position.latitude_deg, 48.0 + 19 * 1e-5);
}

// The keyframes' pictures the aircraft sends down are kept with the merger's records, each under
// its frame's COLMAP name with a line of the index; a picture that is not what it says is refused
// before anything is decoded or written.
TEST(MergerServiceInProcess, KeepsTheKeyframesPicturesAndRefusesOnesThatAreNotWhatTheySay) {
  const StitchConfig config = ShortFlight();
  const Vocabulary vocabulary = LoadVocabulary(config);
  testing::TempDir dir;
  MergerOnMemq merger(config, vocabulary, dir.path().string());
  const auto picture = [](int frame) {
    stitch::keyframe_image_t m{};
    const SubmapId submap = MakeSubmapId(0, 1);
    m.submap_id = submap.value;
    m.keyframe_id = MakeKeyframeId(submap, frame).value;
    m.frame_index = frame;
    m.t_ns = frame * 50'000'000LL;
    m.camera_width = 640;
    m.camera_height = 480;
    cv::Mat image(120, 160, CV_8UC1);
    cv::randu(image, 0, 255);
    cv::imencode(".jpg", image, m.jpeg);
    m.width = 160;
    m.height = 120;
    m.num_bytes = static_cast<int32_t>(m.jpeg.size());
    return m;
  };
  merger.Send(picture(4));
  merger.Send(picture(30));
  stitch::keyframe_image_t claims_more = picture(40);  // a 160x120 JPEG said to be 16000x12000
  claims_more.width = 16000;
  claims_more.height = 12000;
  claims_more.camera_width = 16000;
  claims_more.camera_height = 12000;
  merger.Send(claims_more);
  stitch::keyframe_image_t not_jpeg = picture(41);
  std::fill(not_jpeg.jpeg.begin(), not_jpeg.jpeg.end(), 0xFF);
  merger.Send(not_jpeg);
  stitch::keyframe_image_t other_submap = picture(42);  // a keyframe of another submap than it names
  other_submap.keyframe_id = MakeKeyframeId(MakeSubmapId(0, 7), 42).value;
  merger.Send(other_submap);
  stitch::keyframe_image_t larger_than_camera = picture(43);
  larger_than_camera.camera_width = 100;
  merger.Send(larger_than_camera);
  merger.Finish();
  const std::vector<KeyframePicture> kept = ReadKeyframePictureIndex(dir.path().string());
  ASSERT_EQ(kept.size(), 2u);
  EXPECT_EQ(kept[0].frame_index, 4);
  EXPECT_EQ(kept[1].frame_index, 30);
  EXPECT_EQ(kept[1].width, 160);
  EXPECT_EQ(kept[1].camera_width, 640);
  const cv::Mat back = cv::imread(dir / ("keyframe_images/" + KeyframePictureName(0, 30)), cv::IMREAD_UNCHANGED);
  EXPECT_EQ(back.size(), cv::Size(160, 120));
  for (int refused : {40, 41, 42, 43}) {
    EXPECT_FALSE(std::filesystem::exists(dir / ("keyframe_images/" + KeyframePictureName(0, refused)))) << refused;
  }
}

}  // namespace
}  // namespace stitch
