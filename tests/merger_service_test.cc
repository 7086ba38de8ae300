// The merger service on an in-process bus (memq://), fed what a mapper sends on <agent>/SUBMAP
// during the short flight, with hostile updates between the real ones.

#include <climits>

#include <gtest/gtest.h>

#include "services/common/map_convert.h"
#include "services/merger/merger_service.h"
#include "stitch/config/stitch_config.h"
#include "stitch/pipeline/inline_pipeline.h"
#include "stitch/source/source.h"
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
  MergerOnMemq(const StitchConfig& config, const Vocabulary& vocabulary)
      : lcm_(bus::OpenLcm("memq://")),
        publisher_(lcm_.get(), "uav0"),
        merger_(lcm_.get(), &publisher_, config.merger, config.tracker.tracking.orb, &vocabulary, ""),
        dispatcher_(lcm_.get()) {
    dispatcher_.Start();
    merger_.Start();
  }
  void Send(stitch::submap_update_t message) { publisher_.Publish(bus::Channel("uav0", bus::kSubmap), &message); }
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

}  // namespace
}  // namespace stitch
