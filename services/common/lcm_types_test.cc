// Every message type round-trips, and the keyframe stays compact.

#include <sys/resource.h>

#include <algorithm>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "stitch/frame_ack_t.hpp"
#include "stitch/frame_t.hpp"
#include "stitch/global_map_t.hpp"
#include "stitch/keyframe_t.hpp"
#include "stitch/local_map_update_t.hpp"
#include "stitch/sequence_info_t.hpp"
#include "stitch/service_status_t.hpp"
#include "stitch/submap_update_t.hpp"
#include "stitch/tracking_status_t.hpp"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

// Encodes, decodes into a fresh object, encodes again: both encodings must be identical.
template <class Message>
Message RoundTrip(const Message& message) {
  std::vector<uint8_t> bytes(message.getEncodedSize());
  EXPECT_EQ(message.encode(bytes.data(), 0, static_cast<int>(bytes.size())), static_cast<int>(bytes.size()));
  Message decoded;
  EXPECT_EQ(decoded.decode(bytes.data(), 0, static_cast<int>(bytes.size())), static_cast<int>(bytes.size()));
  std::vector<uint8_t> again(decoded.getEncodedSize());
  decoded.encode(again.data(), 0, static_cast<int>(again.size()));
  EXPECT_EQ(bytes, again) << Message::getTypeName();
  return decoded;
}

stitch::header_t Header(int64_t seq) {
  stitch::header_t h{};
  h.agent = "uav7";
  h.sender_session = 0x1234567890LL;
  h.seq = seq;
  h.utime = 1700000000000000LL + seq;
  return h;
}

stitch::rigid3_t Pose(double a) {
  stitch::rigid3_t p;
  p.rotation_wxyz[0] = std::cos(a);
  p.rotation_wxyz[3] = std::sin(a);
  p.translation[0] = a;
  p.translation[1] = -2 * a;
  p.translation[2] = 3;
  return p;
}

stitch::sim3_t Sim(double s) {
  stitch::sim3_t m;
  m.scale = s;
  m.rotation_wxyz[0] = 1;
  m.translation[2] = s;
  return m;
}

stitch::camera_t Camera() {
  stitch::camera_t c{};
  c.model = stitch::camera_t::MODEL_PINHOLE_RADTAN;
  c.width = 752;
  c.height = 480;
  c.params = {458.654, 457.296, 367.215, 248.375, -0.28, 0.07, 0.0002, 0.00002, 0};
  c.num_params = 9;
  return c;
}

stitch::keyframe_t Keyframe(int num_features, uint64_t seed) {
  Rng rng(seed);
  stitch::keyframe_t k{};
  k.header = Header(3);
  k.keyframe_id = (7LL << 48) | (2LL << 32) | 41;
  k.submap_id = (7LL << 48) | (2LL << 32);
  k.frame_index = 1234;
  k.t_ns = 1403715273262142976LL;
  k.cam_from_submap = Pose(0.3);
  k.camera = Camera();
  k.num_features = num_features;
  for (int i = 0; i < num_features; ++i) {
    k.x_eighth_px.push_back(static_cast<int16_t>(rng.UniformInt(0, 751 * 8)));
    k.y_eighth_px.push_back(static_cast<int16_t>(rng.UniformInt(0, 479 * 8)));
    k.octave.push_back(static_cast<int8_t>(rng.UniformInt(0, 7)));
    k.angle.push_back(static_cast<int8_t>(rng.UniformInt(-128, 127)));
    k.point_index.push_back(rng.Uniform() < 0.5 ? -1 : rng.UniformInt(0, 100000));
  }
  k.num_descriptor_bytes = 32 * num_features;
  for (int i = 0; i < 32 * num_features; ++i) k.descriptors.push_back(static_cast<uint8_t>(rng.NextU64()));
  return k;
}

stitch::map_point_t Point(int index) {
  stitch::map_point_t p{};
  p.point_index = index;
  p.position[0] = 1.5f * index;
  p.viewing_direction[2] = -1;
  p.min_distance = 0.5f;
  p.max_distance = 9.0f;
  for (int i = 0; i < 32; ++i) p.descriptor[i] = static_cast<uint8_t>(i * index);
  p.num_observations = 4;
  return p;
}

TEST(LcmTypes, FrameRoundTrips) {
  stitch::frame_t f{};
  f.header = Header(9);
  f.t_ns = 42;
  f.frame_index = 9;
  f.frames_total = 100;
  f.camera_id = 0;
  f.camera = Camera();
  f.encoding = stitch::frame_t::ENCODING_GRAY8;
  f.width = 4;
  f.height = 2;
  f.data = {1, 2, 3, 4, 5, 6, 7, 8};
  f.num_bytes = 8;
  const auto back = RoundTrip(f);
  EXPECT_EQ(back.header.agent, "uav7");
  EXPECT_EQ(back.data, f.data);
  EXPECT_EQ(back.camera.params, f.camera.params);
}

TEST(LcmTypes, SmallMessagesRoundTrip) {
  stitch::frame_ack_t ack{};
  ack.header = Header(1);
  ack.frame_index = 5;
  ack.t_ns = 77;
  EXPECT_EQ(RoundTrip(ack).frame_index, 5);

  stitch::sequence_info_t info{};
  info.header = Header(2);
  info.source = "synthetic seed=1";
  info.frames_total = 1000;
  info.frames_published = 10;
  info.nominal_fps = 20;
  info.finished = true;
  EXPECT_TRUE(RoundTrip(info).finished);

  stitch::tracking_status_t status{};
  status.header = Header(3);
  status.frame_index = 10;
  status.state = stitch::tracking_status_t::STATE_LOST;
  status.reason = stitch::tracking_status_t::REASON_TOO_FEW_MATCHES;
  status.detail = "12 matches";
  status.submap_id = 99;
  status.cam_from_submap = Pose(0.1);
  status.tracking_ms = 7.5f;
  EXPECT_EQ(RoundTrip(status).detail, "12 matches");

  stitch::service_status_t service{};
  service.header = Header(4);
  service.service = "tracker";
  service.state = stitch::service_status_t::STATE_FINISHED;
  service.items_in = 1000;
  EXPECT_EQ(RoundTrip(service).items_in, 1000);
}

TEST(LcmTypes, MapMessagesRoundTrip) {
  stitch::keyframe_t keyframe = Keyframe(50, 1);
  const auto k = RoundTrip(keyframe);
  EXPECT_EQ(k.descriptors, keyframe.descriptors);
  EXPECT_EQ(k.point_index, keyframe.point_index);

  stitch::local_map_update_t local{};
  local.header = Header(5);
  local.submap_id = 3;
  local.revision = 8;
  local.last_keyframe_id = 41;
  local.num_keyframes = 2;
  local.keyframe_ids = {40, 41};
  local.cam_from_submap = {Pose(0.1), Pose(0.2)};
  local.num_points = 2;
  local.points = {Point(1), Point(2)};
  local.num_removed_points = 1;
  local.removed_point_index = {7};
  local.num_removed_keyframes = 0;
  local.num_parts = 1;
  stitch::keyframe_association_t association{};
  association.keyframe_id = 41;
  association.point_index = {-1, 3, 7};
  association.num_features = 3;
  local.associations = {association};
  local.num_associations = 1;
  const auto local_back = RoundTrip(local);
  EXPECT_EQ(local_back.points[1].point_index, 2);
  EXPECT_EQ(local_back.associations[0].point_index[2], 7);

  stitch::submap_update_t submap{};
  submap.header = Header(6);
  submap.submap_id = 3;
  submap.revision = 2;
  submap.closed = true;
  submap.num_parts = 1;
  submap.num_keyframes = 2;
  submap.keyframes = {Keyframe(10, 2), Keyframe(20, 3)};
  submap.num_points = 1;
  submap.points = {Point(5)};
  submap.num_removed_points = 0;
  submap.num_manifest = 3;
  submap.manifest_keyframe_ids = {1, 2, 3};
  EXPECT_EQ(RoundTrip(submap).keyframes[1].num_features, 20);

  stitch::global_map_t global{};
  global.header = Header(7);
  global.revision = 1;
  stitch::submap_placement_t placement{};
  placement.agent = "uav7";
  placement.submap_id = 3;
  placement.component = 0;
  placement.world_from_submap = Sim(2.0);
  global.submaps = {placement};
  global.num_submaps = 1;
  stitch::submap_edge_t edge{};
  edge.submap_a = 3;
  edge.submap_b = 4;
  edge.strength = 12.5;
  edge.b_from_a = Sim(0.5);
  global.edges = {edge};
  global.num_edges = 1;
  stitch::trajectory_pose_t pose{};
  pose.frame_index = 1;
  pose.world_from_cam = Sim(1.0);
  global.trajectory = {pose, pose};
  global.num_poses = 2;
  stitch::map_on_earth_t on_earth{};
  on_earth.component = 0;
  on_earth.enu_from_world = Sim(3.5);
  on_earth.origin_latitude_deg = 47.4;
  on_earth.inlier_fixes = 120;
  global.on_earth = {on_earth};
  global.num_on_earth = 1;
  const auto g = RoundTrip(global);
  EXPECT_DOUBLE_EQ(g.edges[0].strength, 12.5);
  EXPECT_DOUBLE_EQ(g.submaps[0].world_from_submap.scale, 2.0);
  ASSERT_EQ(g.num_on_earth, 1);
  EXPECT_DOUBLE_EQ(g.on_earth[0].enu_from_world.scale, 3.5);
  EXPECT_DOUBLE_EQ(g.on_earth[0].origin_latitude_deg, 47.4);
  EXPECT_EQ(g.on_earth[0].inlier_fixes, 120);
}

TEST(LcmTypes, KeyframeOfAThousandFeaturesIsAbout42kB) {
  const stitch::keyframe_t keyframe = Keyframe(1000, 5);
  const int bytes = keyframe.getEncodedSize();
  // 42 bytes per feature (x, y: 2+2; octave, angle: 1+1; descriptor 32; point index 4) plus the
  // fixed part (header, ids, pose, calibration). docs/messages.md quotes this figure.
  EXPECT_EQ(bytes - Keyframe(0, 5).getEncodedSize(), 42 * 1000);
  EXPECT_LE(bytes, 42'300);
  std::printf("keyframe_t with 1000 features: %d bytes\n", bytes);
}

TEST(LcmTypes, ATypeDoesNotDecodeAsAnother) {
  stitch::frame_ack_t ack{};
  ack.header = Header(1);
  std::vector<uint8_t> bytes(ack.getEncodedSize());
  ack.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  stitch::tracking_status_t status{};
  EXPECT_LT(status.decode(bytes.data(), 0, static_cast<int>(bytes.size())), 0);
}

// Peak resident memory of this process so far, in MB.
double PeakResidentMb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024.0;
}

// The security issue's row: a 4 MB SUBMAP whose keyframe count equals the bytes left passed the
// count check (one byte an element) and the decode's resize took the merger from 65 to 1,560 MB
// (a keyframe_t is 376 bytes in memory). Counts are checked at the fewest bytes an element takes
// on the wire now: each array's count set to the bytes left is refused before anything grows.
TEST(LcmTypes, ACountItsMessageCannotHoldIsRefusedBeforeAnythingIsAllocated) {
  EXPECT_EQ(stitch_lcm::MinEncodedBytes<std::string>(), 5);
  EXPECT_EQ(stitch_lcm::MinEncodedBytes<double>(), 8);
  EXPECT_EQ(stitch_lcm::MinEncodedBytes<int8_t>(), 1);
  EXPECT_GT(stitch_lcm::MinEncodedBytes<stitch::keyframe_t>(), 100);
  EXPECT_TRUE(stitch_lcm::CountFits<double>(10, 80));
  EXPECT_FALSE(stitch_lcm::CountFits<double>(11, 80));
  EXPECT_FALSE(stitch_lcm::CountFits<double>(-1, 80));
  stitch::submap_update_t update{};
  update.header = Header(3);
  std::vector<uint8_t> empty(update.getEncodedSize());
  ASSERT_EQ(update.encode(empty.data(), 0, static_cast<int>(empty.size())), static_cast<int>(empty.size()));
  // Where each count sits: after the hash (8), the header, the id (8), revision, part and
  // num_parts (4 each), two booleans (1 each).
  const size_t keyframes_at = 8 + update.header._getEncodedSizeNoHash() + 8 + 12 + 2;
  const size_t poses_at = keyframes_at + 4, associations_at = poses_at + 4, points_at = associations_at + 4;
  const double before_mb = PeakResidentMb();
  constexpr size_t kMessageBytes = 4 << 20;
  for (const size_t count_at : {keyframes_at, poses_at, associations_at, points_at}) {
    std::vector<uint8_t> bytes(kMessageBytes, 0);
    std::copy(empty.begin(), empty.end(), bytes.begin());
    const uint32_t count = static_cast<uint32_t>(kMessageBytes - count_at - 4);                     // every byte left
    for (int i = 0; i < 4; ++i) bytes[count_at + i] = static_cast<uint8_t>(count >> (24 - 8 * i));  // big-endian
    stitch::submap_update_t decoded;
    EXPECT_LT(decoded.decode(bytes.data(), 0, static_cast<int>(bytes.size())), 0) << count_at;
  }
  EXPECT_LT(PeakResidentMb() - before_mb, 64) << "a count the message cannot hold made the decode allocate";
}

}  // namespace
}  // namespace stitch
