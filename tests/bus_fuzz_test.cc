// Bad input on the bus: every service is fed malformed messages on each channel of the bus
// (random bytes, truncated and bit-flipped real messages, counts set to absurd values, messages
// of another type, another agent's messages) for a bounded time; none may crash or balloon in
// memory, each counts what it rejected, and the system still maps a flight afterwards.

#include <sys/resource.h>

#include <map>
#include <mutex>
#include <set>

#include <gtest/gtest.h>

#include "services/ingest/ingest_service.h"
#include "services/mapper/mapper_service.h"
#include "services/merger/merger_service.h"
#include "services/tracker/tracker_service.h"
#include "services/viewer/viewer_service.h"
#include "stitch/config/stitch_config.h"
#include "stitch/link_status_t.hpp"
#include "stitch/mosaic_tile_t.hpp"
#include "stitch/service_status_t.hpp"
#include "stitch/source/source.h"
#include "stitch/submap_request_t.hpp"
#include "stitch/tracking_status_t.hpp"
#include "stitch/util/ids.h"
#include "stitch/util/rng.h"
#include "tests/synthetic_flight.h"

namespace stitch {
namespace {

using Bytes = std::vector<uint8_t>;

// The short flight, with an ingest that waits up to a minute for a frame's ack: under
// ThreadSanitizer beside another test on two cores, a frame whose tracker is busy with fuzzed
// keyframes took more than the default 10 s (CI, stop 24), and a frame given up on is not what
// this test is about.
StitchConfig PatientConfig() {
  StitchConfig config = LoadStitchConfig(std::string(STITCH_SOURCE_DIR) + "/tests/short_flight.yaml");
  config.ingest.max_resends = 240;
  return config;
}

ViewerOptions ViewerOnAPortOfItsOwn() {
  ViewerOptions options;
  options.port = bus::UnusedTcpPort();
  return options;
}

struct Stack {
  explicit Stack(const std::string& failures)
      : config(PatientConfig()),
        vocabulary(LoadVocabulary(config)),
        lcm(bus::OpenLcm("memq://")),
        publisher(lcm.get(), "uav0"),
        ingest(lcm.get(), "memq://", &publisher, config.ingest),
        tracker(lcm.get(), &publisher, config.tracker, &vocabulary, ""),
        mapper(lcm.get(), &publisher, config.mapper, config.tracker.tracking.orb, &vocabulary, ""),
        merger(lcm.get(), &publisher, config.merger, config.tracker.tracking.orb, &vocabulary, ""),
        viewer(lcm.get(), &publisher, ViewerOnAPortOfItsOwn()),
        failures(failures) {}

  void Start() {
    viewer.Start();
    merger.Start();
    mapper.Start();
    tracker.Start();
  }
  IngestSummary Fly() { return testing::PlaySyntheticFlight(ingest, config.synthetic, failures); }
  void Stop() {
    tracker.Stop();
    mapper.Stop();
    merger.Stop();
    viewer.Stop();
  }

  StitchConfig config;
  Vocabulary vocabulary;
  std::unique_ptr<lcm::LCM> lcm;
  bus::Publisher publisher;
  IngestService ingest;
  TrackerService tracker;
  MapperService mapper;
  MergerService merger;
  ViewerService viewer;
  std::string failures;
};

// The channels the services listen to (and those they publish, which some tool may listen to),
// and the first few real messages seen on each.
const std::vector<std::string> kChannels = {"FRAME",      "FRAME_ACK",      "LOCAL_MAP",       "KEYFRAME",
                                            "POSE",       "SUBMAP",         "TRACKING_STATUS", "SERVICE",
                                            "SEQUENCE",   "MAP_CLOUD",      "SUBMAP_REQUEST",  "LINK_STATUS",
                                            "GLOBAL_MAP", "KEYFRAME_IMAGE", "MOSAIC_TILE"};

template <class Message>
Bytes Encoded(const Message& message) {
  Bytes bytes(static_cast<size_t>(message.getEncodedSize()));
  message.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  return bytes;
}

// Well-formed seeds for the channels a flight on one bus may not use: a link bridge's status
// and the merger's requests for what the link lost.
void AddLinkSeeds(std::map<std::string, std::vector<Bytes>>* seeds) {
  if ((*seeds)["LINK_STATUS"].empty()) {
    stitch::link_status_t status{};
    status.forward = "uav0/(SUBMAP|SEQUENCE)";
    status.peer = "10.0.0.2:7000";
    status.budget_bytes_per_s = 100000;
    status.send_rate_bytes_per_s = 42000;
    status.queued_bytes = 5000;
    status.backlog_s = 0.05;
    status.authenticated = true;
    status.seconds_since_peer = 0.2;
    (*seeds)["LINK_STATUS"].push_back(Encoded(status));
  }
  if ((*seeds)["MOSAIC_TILE"].empty()) {  // the merger's, once its mosaic has started
    stitch::mosaic_tile_t tile{};
    tile.revision = 1;
    tile.frame_submap = MakeSubmapId(0, 1).value;
    tile.ground_from_map.scale = 1;
    tile.ground_from_map.rotation_wxyz[0] = 1;
    tile.gsd = 0.01;
    tile.tile_px = 16;
    tile.version = 1;
    tile.png = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n', 0, 0, 0, 13, 'I', 'H', 'D', 'R', 0, 0, 0, 16, 0, 0, 0, 16};
    tile.num_bytes = static_cast<int32_t>(tile.png.size());
    (*seeds)["MOSAIC_TILE"].push_back(Encoded(tile));
  }
  if ((*seeds)["SUBMAP_REQUEST"].empty()) {
    stitch::submap_request_t request{};
    request.submap_id = MakeSubmapId(0, 1).value;
    request.full_state = true;
    request.keyframe_ids = {MakeKeyframeId(MakeSubmapId(0, 1), 3).value, MakeKeyframeId(MakeSubmapId(0, 1), 4).value};
    request.num_keyframes = 2;
    (*seeds)["SUBMAP_REQUEST"].push_back(Encoded(request));
  }
}

std::map<std::string, std::vector<Bytes>> RecordSeeds() {
  Stack stack("30:6");
  std::map<std::string, std::vector<Bytes>> seeds;
  std::mutex mutex;
  struct Recorder {
    std::map<std::string, std::vector<Bytes>>* seeds;
    std::mutex* mutex;
    void On(const lcm::ReceiveBuffer* buffer, const std::string& channel) {
      std::lock_guard<std::mutex> lock(*mutex);
      auto& list = (*seeds)[channel.substr(channel.find('/') + 1)];
      const auto* data = static_cast<const uint8_t*>(buffer->data);
      if (list.size() < 6) list.emplace_back(data, data + buffer->data_size);
    }
  } recorder{&seeds, &mutex};
  auto* subscription = stack.lcm->subscribe("uav0/.*", &Recorder::On, &recorder);
  bus::Dispatcher dispatcher(stack.lcm.get());
  dispatcher.Start();
  stack.Start();
  stack.Fly();
  stack.Stop();
  dispatcher.Stop();
  stack.lcm->unsubscribe(subscription);
  AddLinkSeeds(&seeds);
  return seeds;
}

// One malformed message made from `seed` (a real message on the channel) or `other` (one of
// another type).
Bytes Mutate(const Bytes& seed, const Bytes& other, Rng* rng) {
  Bytes m = seed;
  switch (rng->UniformInt(0, 5)) {
    case 0: {  // random bytes
      m.resize(static_cast<size_t>(rng->UniformInt(0, 512)));
      for (auto& b : m) b = static_cast<uint8_t>(rng->UniformInt(0, 255));
      break;
    }
    case 1:  // truncated
      m.resize(static_cast<size_t>(rng->UniformInt(0, static_cast<int>(m.size()))));
      break;
    case 2:  // a few bytes flipped
      for (int i = rng->UniformInt(1, 8); i > 0 && !m.empty(); --i) {
        m[static_cast<size_t>(rng->UniformInt(0, static_cast<int>(m.size()) - 1))] ^=
            static_cast<uint8_t>(1 << rng->UniformInt(0, 7));
      }
      break;
    case 3: {  // an aligned int32 (a count, often) set to an absurd value
      if (m.size() < 12) break;
      const size_t at = 8 + 4 * static_cast<size_t>(rng->UniformInt(0, static_cast<int>((m.size() - 12) / 4)));
      const uint32_t values[] = {0x7fffffffu, 0x80000000u, 0xffffffffu, 100000000u, 1u << 24, 65537u};
      const uint32_t v = values[rng->UniformInt(0, 5)];
      for (int b = 0; b < 4; ++b) m[at + b] = static_cast<uint8_t>(v >> (24 - 8 * b));
      break;
    }
    case 4:  // a message of another type
      m = other;
      break;
    case 5:  // trailing bytes
      m.push_back(static_cast<uint8_t>(rng->UniformInt(0, 255)));
      break;
  }
  return m;
}

long PeakResidentMb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024;
}

TEST(BusFuzz, MalformedMessagesOnEveryChannelAreRejectedAndTheServicesKeepWorking) {
  const auto seeds = RecordSeeds();
  for (const std::string& channel : kChannels) {
    ASSERT_TRUE(seeds.count(channel) && !seeds.at(channel).empty()) << "no message seen on " << channel;
  }
  Stack stack("none");
  // The services' own counts of rejected messages, from their heartbeats.
  std::mutex mutex;
  std::map<std::string, int64_t> rejected;
  bus::Subscriber statuses(stack.lcm.get());
  statuses.Subscribe<stitch::service_status_t>(
      bus::Channel("uav0", bus::kService), [&](std::unique_ptr<stitch::service_status_t> s, const std::string&) {
        std::lock_guard<std::mutex> lock(mutex);
        rejected[s->service] = std::max(rejected[s->service], s->items_rejected);
      });
  bus::Dispatcher dispatcher(stack.lcm.get());
  dispatcher.Start();
  stack.Start();

  Rng rng(2026);
  int sent = 0;
  for (int round = 0; round < 200; ++round) {  // 13 channels: 2600 messages
    for (size_t c = 0; c < kChannels.size(); ++c) {
      const auto& own = seeds.at(kChannels[c]);
      const auto& other = seeds.at(kChannels[(c + 1 + static_cast<size_t>(rng.UniformInt(0, 5))) % kChannels.size()]);
      const Bytes message =
          Mutate(own[static_cast<size_t>(rng.UniformInt(0, static_cast<int>(own.size()) - 1))], other[0], &rng);
      // Also now and then on another agent's channel, which nobody here listens to.
      const std::string agent = rng.UniformInt(0, 9) == 0 ? "uav7" : "uav0";
      stack.lcm->publish(agent + "/" + kChannels[c], message.data(), static_cast<unsigned>(message.size()));
      ++sent;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  // Handled, and a heartbeat out: the heartbeats queue behind the malformed messages on the one
  // dispatcher thread, which under a sanitizer, beside other tests, takes many seconds.
  const auto all_counted = [&] {
    std::lock_guard<std::mutex> lock(mutex);
    for (const char* service : {"tracker", "mapper", "merger", "viewer"}) {
      if (rejected[service] <= 50) return false;
    }
    return true;
  };
  for (int waited_ms = 0; waited_ms < 120'000 && !all_counted(); waited_ms += 100) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  EXPECT_LT(PeakResidentMb(), 3000) << "an absurd count made someone allocate";
  {
    std::lock_guard<std::mutex> lock(mutex);
    for (const char* service : {"tracker", "mapper", "merger", "viewer"}) {
      EXPECT_GT(rejected[service], 50) << service << " rejected too few of " << sent << " malformed messages";
    }
  }
  // Still working: a calm flight is tracked and mapped. (Mutated messages that still decode are
  // input like any other, e.g. keyframes of an earlier flight under the same agent, so the flight
  // may start a fresh submap before it settles.)
  std::set<int> posed;
  statuses.Subscribe<stitch::tracking_status_t>(bus::Channel("uav0", bus::kTrackingStatus),
                                                [&](std::unique_ptr<stitch::tracking_status_t> s, const std::string&) {
                                                  std::lock_guard<std::mutex> lock(mutex);
                                                  if (s->state == stitch::tracking_status_t::STATE_OK)
                                                    posed.insert(s->frame_index);
                                                });
  const int64_t mapped_before = stack.mapper.keyframes_mapped();
  const IngestSummary summary = stack.Fly();
  stack.Stop();
  dispatcher.Stop();
  EXPECT_EQ(summary.frames_unacked, 0);
  EXPECT_GE(posed.size(), 40u) << "of the flight's 60 frames";
  EXPECT_GT(stack.mapper.keyframes_mapped(), mapped_before + 3);
}

}  // namespace
}  // namespace stitch
