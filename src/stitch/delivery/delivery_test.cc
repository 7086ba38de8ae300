// The submap delivery protocol end to end without a bus: a mapper's SubmapSender and a merger's
// SubmapReceiver joined by a simulated link that loses, repeats and reorders what it carries in
// both directions, on a simulated clock. The merger ends with every submap as the mapper holds
// it, and the mapper hears that it does, through the loss and a restart of either end.

#include <algorithm>
#include <cstdio>
#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <set>

#include <gtest/gtest.h>

#include "stitch/delivery/submap_receiver.h"
#include "stitch/delivery/submap_sender.h"
#include "stitch/testing/submap_updates.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

const Camera kCamera = Camera::Pinhole(640, 480, 400, 400, 320, 240);
const ScalePyramid kPyramid = ScalePyramid::From(OrbOptions());

// The mapper's submaps (what LocalMapping holds), each grown keyframe by keyframe
// (testing::AddChainedKeyframe: every new keyframe refines the points it shares).
class FakeMapper : public SubmapSource {
 public:
  const Map* current() const override { return current_.get(); }
  std::vector<SubmapId> closed() const override {
    std::vector<SubmapId> ids;
    for (const auto& map : closed_) ids.push_back(map->id());
    return ids;
  }
  bool Holds(SubmapId submap) const override { return Find(submap) != nullptr; }
  bool Holds(KeyframeId keyframe) const override {
    const Map* map = Find(SubmapOf(keyframe));
    return map && map->FindKeyframe(keyframe);
  }
  // As LocalMapping::MakeResendUpdate.
  SubmapUpdate MakeResendUpdate(SubmapId submap, const std::vector<KeyframeId>& keyframes, bool full_state) override {
    Map* found = Find(submap);
    if (!found) return {};
    const bool closed = found != current_.get();
    const bool keyframes_alone = closed && !full_state;
    return MakeResendSubmapUpdate(found, kCamera, keyframes, full_state, closed, keyframes_alone ? 0 : ++revision_);
  }
  SubmapUpdate MakeManifestUpdate() override {
    return current_ ? MakeManifestSubmapUpdate(*current_, kCamera, ++revision_) : SubmapUpdate();
  }

  // The next keyframe's update (the keyframe in full and its window's changes); a new submap
  // starts after Close.
  SubmapUpdate AddKeyframe() {
    if (!current_) {
      current_ = std::make_unique<Map>(MakeSubmapId(0, static_cast<uint32_t>(++submaps_)), kPyramid);
      current_->EnableRemovalJournal();
      index_ = 0;
    }
    const KeyframeId id = testing::AddChainedKeyframe(current_.get(), index_++, /*refine_m=*/0.2);
    const LocalMapUpdate changes = MakeLocalMapUpdate(current_.get(), id, ++revision_, 0);
    return MakeKeyframeSubmapUpdate(*current_, id, kCamera, changes);
  }
  // Closes the current submap; its final state.
  SubmapUpdate Close() {
    Map* map = current_.get();
    closed_.push_back(std::move(current_));
    return MakeFullSubmapUpdate(map, ++revision_, /*closed=*/true);
  }
  const std::vector<std::unique_ptr<Map>>& closed_maps() const { return closed_; }

 private:
  Map* Find(SubmapId submap) const {
    if (current_ && current_->id() == submap) return current_.get();
    for (const auto& map : closed_) {
      if (map->id() == submap) return map.get();
    }
    return nullptr;
  }
  std::unique_ptr<Map> current_;
  std::vector<std::unique_ptr<Map>> closed_;
  int submaps_ = 0;
  uint32_t index_ = 0;
  int revision_ = 0;
};

// A link one way: each message is lost with `loss`, sent twice with `duplication`, and delayed
// by 0-`max_delay_s` (so messages overtake each other).
template <class Message>
class SimulatedLink {
 public:
  SimulatedLink(double loss, double duplication, double max_delay_s, uint64_t seed)
      : loss_(loss), duplication_(duplication), max_delay_s_(max_delay_s), rng_(seed) {}
  void Send(const Message& message, double now) {
    for (int copy = 0; copy < (rng_.Uniform() < duplication_ ? 2 : 1); ++copy) {
      if (rng_.Uniform() < loss_) {
        ++lost_;
        continue;
      }
      in_flight_.push_back({now + rng_.Uniform(0, max_delay_s_), message});
    }
  }
  // What has arrived by `now`, in order of arrival.
  std::vector<Message> Arrived(double now) {
    std::stable_sort(in_flight_.begin(), in_flight_.end(),
                     [](const auto& a, const auto& b) { return a.first < b.first; });
    std::vector<Message> arrived;
    while (!in_flight_.empty() && in_flight_.front().first <= now) {
      arrived.push_back(std::move(in_flight_.front().second));
      in_flight_.pop_front();
    }
    return arrived;
  }
  int lost() const { return lost_; }

 private:
  double loss_, duplication_, max_delay_s_;
  Rng rng_;
  std::deque<std::pair<double, Message>> in_flight_;
  int lost_ = 0;
};

struct Part {
  SubmapUpdate update;
  int32_t index = 0, count = 1;
};

// The merger's side as the merger service runs it: plausible revisions only, every part applied
// to its submap's copy and journaled, the receiver told; a restart replays the journal into a
// new receiver.
class Ground {
 public:
  explicit Ground(const ReceiverOptions& options, const DeliveryClock& clock) : options_(options), clock_(clock) {
    receiver_ = std::make_unique<SubmapReceiver>(options_, clock_);
  }
  void Take(const Part& part, bool from_journal = false) {
    std::string why;
    if (!from_journal && !receiver_->PlausibleRevision("uav0", part.update.revision, &why)) return;
    if (!from_journal) journal_.push_back(part);
    SubmapReplica& replica = replicas_.try_emplace(part.update.submap, part.update.submap, kPyramid).first->second;
    const std::vector<KeyframeId> missing = ApplySubmapUpdate(part.update, &replica);
    receiver_->Received(part.update, part.index, part.count, &replica, missing.size());
  }
  std::vector<DeliveryRequest> Requests() { return receiver_->Requests(replicas_); }
  // A merger killed and started again on its journal: what was in flight to it is lost.
  void Restart() {
    replicas_.clear();
    receiver_ = std::make_unique<SubmapReceiver>(options_, clock_);
    for (const Part& part : journal_) Take(part, /*from_journal=*/true);
  }
  const std::map<SubmapId, SubmapReplica>& replicas() const { return replicas_; }

 private:
  ReceiverOptions options_;
  DeliveryClock clock_;
  std::unique_ptr<SubmapReceiver> receiver_;
  std::map<SubmapId, SubmapReplica> replicas_;
  std::vector<Part> journal_;
};

struct Flight {
  double loss = 0.3, duplication = 0.1, max_delay_s = 0.3;
  bool request_resends = true;
  int submaps = 4, keyframes_per_submap = 10;
  double restart_ground_at_s = -1, restart_aircraft_at_s = -1;  // < 0: never
  std::function<bool(const Part&)> drop_down;                   // parts the link loses besides
};

struct Delivered {
  int submaps_whole = 0;      // closed on the ground with every keyframe and point as the mapper's
  int submaps_confirmed = 0;  // the mapper heard the merger holds them whole
  bool linger_ended_early = false;
  double seconds = 0;  // the linger at stop
  int lost_down = 0, lost_up = 0;
  int64_t resends = 0;  // of the last sender
};

Delivered Fly(const Flight& flight) {
  double now = 0;
  const DeliveryClock clock = [&now] { return now; };
  SenderOptions sender_options;
  sender_options.stop_linger_s = 30;
  ReceiverOptions receiver_options;
  receiver_options.request_resends = flight.request_resends;
  receiver_options.resend_interval_s = 0.5;
  FakeMapper mapper;
  SimulatedLink<Part> down(flight.loss, flight.duplication, flight.max_delay_s, 11);
  SimulatedLink<DeliveryRequest> up(flight.loss, flight.duplication, flight.max_delay_s, 12);
  const auto transport = [&](const SubmapUpdate& part, int32_t index, int32_t count) {
    if (!flight.drop_down || !flight.drop_down({part, index, count})) down.Send({part, index, count}, now);
    return SubmapSender::PartSent{1000, 0};
  };
  auto sender = std::make_unique<SubmapSender>(sender_options, &mapper, transport, clock, /*max_part_bytes=*/4000);
  Ground ground(receiver_options, clock);
  const auto tick = [&] {
    now += 0.05;
    if (flight.restart_ground_at_s >= 0 && now >= flight.restart_ground_at_s &&
        now < flight.restart_ground_at_s + 0.05) {
      down.Arrived(now);  // lost with the merger's process
      ground.Restart();
    }
    if (flight.restart_aircraft_at_s >= 0 && now >= flight.restart_aircraft_at_s &&
        now < flight.restart_aircraft_at_s + 0.05) {
      up.Arrived(now);  // lost with the mapper's process (its maps survive: the test's mapper is kept)
      sender = std::make_unique<SubmapSender>(sender_options, &mapper, transport, clock, 4000);
    }
    for (const Part& part : down.Arrived(now)) ground.Take(part);
    for (const DeliveryRequest& request : ground.Requests()) up.Send(request, now);
    for (const DeliveryRequest& request : up.Arrived(now)) sender->OnRequest(request);
  };
  for (int s = 0; s < flight.submaps; ++s) {
    for (int k = 0; k < flight.keyframes_per_submap; ++k) {
      sender->SendKeyframeUpdate(mapper.AddKeyframe());
      for (int t = 0; t < 4; ++t) {
        tick();
        sender->AnswerRequests();
        sender->SendManifestIfIdle(t == 0);
      }
    }
    sender->SendFinalState(mapper.Close());
  }
  Delivered delivered;
  const double stop = now;
  sender->StartLinger(mapper.closed_maps().back()->id());
  while (sender->LingerStep()) tick();
  delivered.seconds = now - stop;
  delivered.linger_ended_early = delivered.seconds < sender_options.stop_linger_s;
  for (const auto& map : mapper.closed_maps()) {
    const auto replica = ground.replicas().find(map->id());
    if (replica == ground.replicas().end() || !replica->second.closed) continue;
    const Map& copy = replica->second.map;
    bool same = copy.num_keyframes() == map->num_keyframes() && copy.num_points() == map->num_points();
    for (const auto& [id, point] : map->points()) {
      const MapPoint* received = copy.FindPoint(id);
      same = same && received && (received->position - point.position).norm() < 1e-9;
    }
    delivered.submaps_whole += same;
  }
  std::vector<SubmapId> closed;
  for (const auto& map : mapper.closed_maps()) closed.push_back(map->id());
  delivered.submaps_confirmed = static_cast<int>(sender->HeldWhole(closed).size());
  delivered.lost_down = down.lost();
  delivered.lost_up = up.lost();
  delivered.resends = sender->resends();
  std::printf("lost %d parts down and %d requests up; the last sender sent %lld answers; lingered %.2f s\n",
              delivered.lost_down, delivered.lost_up, static_cast<long long>(delivered.resends), delivered.seconds);
  return delivered;
}

TEST(Delivery, EverySubmapArrivesWholeAndIsConfirmedOnAPerfectLink) {
  Flight perfect;
  perfect.loss = perfect.duplication = perfect.max_delay_s = 0;
  const Delivered delivered = Fly(perfect);
  EXPECT_EQ(delivered.submaps_whole, 4);
  EXPECT_EQ(delivered.submaps_confirmed, 4);
  EXPECT_LT(delivered.seconds, 1.0);
}

// Loss, duplication and reordering both ways, the merger restarted from its journal a third of
// the way through, the mapper's delivery state lost two thirds of the way: every submap ends on
// the ground as the mapper holds it, and the mapper stops once it hears so.
TEST(Delivery, EverySubmapArrivesWholeThroughLossReorderingDuplicationAndRestarts) {
  Flight flight;
  flight.restart_ground_at_s = 2.7;
  flight.restart_aircraft_at_s = 5.4;
  const Delivered delivered = Fly(flight);
  EXPECT_EQ(delivered.submaps_whole, 4);
  EXPECT_EQ(delivered.submaps_confirmed, 4);
  EXPECT_TRUE(delivered.linger_ended_early) << "lingered " << delivered.seconds << " s";
  EXPECT_GT(delivered.lost_down, 10);
  EXPECT_GT(delivered.lost_up, 1);
}

// The last keyframe's update and the first part of the final state (the one with the manifest)
// lost: the final state's other parts alone do not make it whole, so the merger asks for it
// again, learns of the keyframe, gets it, and only then tells the mapper it holds the submap
// whole. Taken whole on its last part, the final state had the merger confirm a submap that
// lacked a keyframe, and the mapper stopped without it.
TEST(Delivery, AFinalStateIsWholeOnlyOnceEveryPartHasArrived) {
  Flight flight;
  flight.loss = flight.duplication = flight.max_delay_s = 0;
  flight.submaps = 1;
  const KeyframeId last = MakeKeyframeId(MakeSubmapId(0, 1), static_cast<uint32_t>(flight.keyframes_per_submap - 1));
  bool final_state_cut = false, final_state_sent = false;
  flight.drop_down = [&](const Part& part) {
    if (part.update.closed) {
      final_state_sent = true;
      if (part.index != 0 || final_state_cut || part.count < 2) return false;
      final_state_cut = true;
      return true;
    }
    if (final_state_sent) return false;  // what is sent again arrives
    const auto names_last = [&](KeyframeId id) { return id == last; };
    return std::any_of(part.update.manifest.begin(), part.update.manifest.end(), names_last) ||
           std::any_of(part.update.new_keyframes.begin(), part.update.new_keyframes.end(),
                       [&](const Keyframe& k) { return k.id == last; });
  };
  const Delivered delivered = Fly(flight);
  ASSERT_TRUE(final_state_cut) << "the final state came in one part";
  EXPECT_EQ(delivered.submaps_whole, 1);
  EXPECT_EQ(delivered.submaps_confirmed, 1);
  EXPECT_GT(delivered.resends, 0);
}

// Without the merger's requests, the same link leaves submaps incomplete: the test above fails
// when that part of the protocol is gone.
TEST(Delivery, WithoutRequestsALossyLinkLeavesSubmapsIncomplete) {
  Flight flight;
  flight.request_resends = false;
  const Delivered delivered = Fly(flight);
  EXPECT_LT(delivered.submaps_whole, 4);
  EXPECT_EQ(delivered.submaps_confirmed, 0);
}

// A saved map the merger read from a file (merger.prior_map) came from no mapper: nothing of it
// is asked for, however it looks to the receiver (closed, its final state never "arrived").
TEST(Delivery, NothingIsAskedForASavedMap) {
  double now = 0;
  SubmapReceiver receiver(ReceiverOptions(), [&] { return now; });
  std::map<SubmapId, SubmapReplica> replicas;
  for (const SubmapId id : {MakeSubmapId(kSavedMapAgent, 0), MakeSubmapId(0, 1)}) {
    SubmapReplica& replica = replicas.try_emplace(id, id, kPyramid).first->second;
    replica.closed = true;
    replica.manifest = {MakeKeyframeId(id, 0)};  // listed, never received
  }
  now = 100;
  receiver.Requests(replicas);
  now = 200;
  const std::vector<DeliveryRequest> requests = receiver.Requests(replicas);
  ASSERT_EQ(requests.size(), 1u);
  EXPECT_EQ(requests[0].submap, MakeSubmapId(0, 1)) << "the aircraft's submap only";
}

}  // namespace
}  // namespace stitch
