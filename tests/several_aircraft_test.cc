// Two aircraft, one merger: each flies half of the survey (the first strip and the turn, the
// turn and the second strip; neighbouring strips share 60% of their footprint) with its own
// agent name and agent number; the merger listens to both and joins their submaps into one map.

#include <chrono>
#include <thread>

#include <gtest/gtest.h>

#include "services/common/map_convert.h"
#include "services/merger/merger_service.h"
#include "stitch/config/stitch_config.h"
#include "stitch/pipeline/inline_pipeline.h"
#include "stitch/source/source.h"

namespace stitch {
namespace {

using namespace std::chrono_literals;

// What aircraft `agent_number` sends on SUBMAP flying frames [first, first + count).
std::vector<stitch::submap_update_t> Fly(int agent_number, int first, int count, StitchConfig config) {
  config.tracker.tracking.agent_number = agent_number;
  SourceSpec spec;
  spec.synthetic = config.synthetic;
  spec.failures = "none";
  spec.start_frame = first;
  spec.max_frames = count;
  FailureSchedule unused;
  auto sequence = OpenSource(spec, &unused);
  const Vocabulary vocabulary = LoadVocabulary(config);
  return ToMessages(
      RunInline(*sequence, config.pipeline(), vocabulary, nullptr, /*keep_submap_updates=*/true).submap_updates);
}

TEST(SeveralAircraft, TwoAircraftFlyingHalvesOfTheSurveyEndInOneMergedMap) {
  StitchConfig config;
  config.synthetic.flight.num_frames = 460;
  config.synthetic.flight.num_strips = 2;
  std::vector<stitch::submap_update_t> first = Fly(0, 0, 260, config);
  std::vector<stitch::submap_update_t> second = Fly(1, 200, 260, config);
  ASSERT_FALSE(first.empty());
  ASSERT_FALSE(second.empty());

  auto lcm = bus::OpenLcm("memq://");
  bus::Publisher uav0(lcm.get(), "uav0"), uav1(lcm.get(), "uav1"), ground(lcm.get(), "ground");
  const Vocabulary vocabulary = LoadVocabulary(config);
  MergerService merger(lcm.get(), &ground, config.merger, config.tracker.tracking.orb, &vocabulary, "", "",
                       {"uav0", "uav1"});
  bus::Dispatcher dispatcher(lcm.get());
  dispatcher.Start();
  merger.Start();
  // Both in the air at once: their updates interleave.
  for (size_t i = 0; i < std::max(first.size(), second.size()); ++i) {
    if (i < first.size()) uav0.Publish(bus::Channel("uav0", bus::kSubmap), &first[i]);
    if (i < second.size()) uav1.Publish(bus::Channel("uav1", bus::kSubmap), &second[i]);
  }
  const auto deadline = std::chrono::steady_clock::now() + 120s;
  const int64_t total = static_cast<int64_t>(first.size() + second.size());
  while (merger.updates_processed() < total && std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(50ms);
  merger.Stop();
  dispatcher.Stop();
  ASSERT_EQ(merger.updates_processed(), total);

  const Merger::Graph graph = merger.merger().Solve();
  std::set<int> aircraft;
  for (const auto& [id, placement] : graph.placement) {
    aircraft.insert(AgentNumber(id));
    EXPECT_EQ(placement.component, 0) << "submap " << SubmapName(id) << " is not in the merged map";
  }
  EXPECT_EQ(aircraft, (std::set<int>{0, 1}));
  bool across = false;  // an edge joining the two aircraft's submaps
  for (const SubmapEdge& e : graph.tree) across |= AgentNumber(e.a) != AgentNumber(e.b);
  EXPECT_TRUE(across);
}

}  // namespace
}  // namespace stitch
