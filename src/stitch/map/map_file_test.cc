#include "stitch/map/map_file.h"

#include <sodium.h>

#include <random>

#include <gtest/gtest.h>

#include "stitch/testing/submap_updates.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace stitch {
namespace {

const SubmapId kFlight = MakeSubmapId(2, 7);
const SubmapId kSaved = MakeSubmapId(0x7fff, 0);
const Camera kCamera = Camera::Pinhole(640, 480, 400, 400, 320, 240, -0.1, 0.01);
const Camera kOtherCamera = Camera::Pinhole(1280, 720, 900, 900, 640, 360);

// A flight's map of 6 keyframes (the last seen by another camera) and a point no keyframe sees.
Map FlightMap() {
  Map map(kFlight, ScalePyramid::From(OrbOptions()));
  for (uint32_t k = 0; k < 6; ++k) testing::AddChainedKeyframe(&map, 3 * k + 1);
  MapPoint lonely;
  lonely.id = MakeMapPointId(kFlight, 9000);
  map.AddPoint(lonely);
  return map;
}

SavedMap Saved(const Map& map) {
  return MakeSavedMap(
      map, [](KeyframeId kf) { return IndexOf(kf) == 16 ? &kOtherCamera : &kCamera; }, "a test flight", kSaved);
}

// Sets the checksum of a file whose payload a test changed, as a writer would have.
void Reseal(std::string* bytes) {
  unsigned char hash[32];
  crypto_generichash(hash, 32, reinterpret_cast<const unsigned char*>(bytes->data()) + 56, bytes->size() - 56, nullptr,
                     0);
  std::copy(hash, hash + 32, bytes->begin() + 24);
}

std::string RefusalOf(const std::string& bytes) {
  try {
    DecodeMapFile(bytes, kSaved);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST(MapFile, ASavedMapKeepsEveryKeyframeAndSeenPointRenumberedInOneSubmap) {
  const Map flight = FlightMap();
  const SavedMap saved = Saved(flight);
  EXPECT_EQ(saved.map.id(), kSaved);
  EXPECT_EQ(saved.map.num_keyframes(), 6u);
  EXPECT_EQ(saved.map.num_points(), flight.num_points() - 1) << "the point no keyframe sees is left out";
  ASSERT_EQ(saved.cameras.size(), 2u);
  for (uint32_t i = 0; i < 6; ++i) {
    const KeyframeId kf = MakeKeyframeId(kSaved, i);
    const KeyframeId source = MakeKeyframeId(kFlight, 3 * i + 1);
    ASSERT_NE(saved.map.FindKeyframe(kf), nullptr);
    EXPECT_EQ(saved.source_keyframe.at(kf), source.value);
    EXPECT_EQ(saved.CameraOf(kf).width(), i == 5 ? 1280 : 640);
    EXPECT_LT((saved.map.FindKeyframe(kf)->Centre() - flight.FindKeyframe(source)->Centre()).norm(), 1e-12);
    EXPECT_EQ(saved.map.FindKeyframe(kf)->CountPoints(), flight.FindKeyframe(source)->CountPoints());
    EXPECT_EQ(saved.map.FindKeyframe(kf)->covisibility.size(), flight.FindKeyframe(source)->covisibility.size());
  }
}

TEST(MapFile, AKeyframeWithoutACameraIsLeftOutWithThePointsOnlyItSaw) {
  const Map flight = FlightMap();
  const KeyframeId last = MakeKeyframeId(kFlight, 16);
  const SavedMap saved = MakeSavedMap(
      flight, [&](KeyframeId kf) { return kf == last ? nullptr : &kCamera; }, "", kSaved);
  EXPECT_EQ(saved.map.num_keyframes(), 5u);
  ASSERT_EQ(saved.cameras.size(), 1u);
  for (const auto& [id, point] : saved.map.points()) EXPECT_FALSE(point.observations.empty()) << id;
  EXPECT_LT(saved.map.num_points(), Saved(flight).map.num_points());
}

TEST(MapFile, AMapReadAndWrittenAgainIsTheSameBytes) {
  const SavedMap saved = Saved(FlightMap());
  testing::TempDir dir;
  const std::string path = dir / "site.stitchmap";
  WriteMapFile(path, saved);
  const SavedMap read = ReadMapFile(path, kSaved);
  EXPECT_EQ(EncodeMapFile(read), ReadFileBytes(path));
  EXPECT_EQ(read.description, "a test flight");
  ASSERT_EQ(read.cameras.size(), 2u);
  EXPECT_EQ(read.cameras[0].params(), kCamera.params());
  for (const auto& [id, point] : saved.map.points()) {
    const MapPoint* copy = read.map.FindPoint(id);
    ASSERT_NE(copy, nullptr);
    EXPECT_EQ(copy->position, point.position);
    EXPECT_EQ(copy->descriptor, point.descriptor);
    EXPECT_EQ(copy->observations, point.observations);
    EXPECT_EQ(copy->reference_keyframe, point.reference_keyframe);
  }
  for (const auto& [id, keyframe] : saved.map.keyframes()) {
    const Keyframe* copy = read.map.FindKeyframe(id);
    ASSERT_NE(copy, nullptr);
    EXPECT_EQ(copy->points, keyframe.points);
    EXPECT_EQ(copy->cam_from_world.translation, keyframe.cam_from_world.translation);
    EXPECT_EQ(cv::norm(copy->descriptors, keyframe.descriptors, cv::NORM_HAMMING), 0);
    EXPECT_EQ(copy->covisibility, keyframe.covisibility);
  }
  const MapFileSummary summary = SummarizeMapFile(ReadFileBytes(path), read);
  EXPECT_EQ(summary.keyframes, 6);
  EXPECT_EQ(summary.checksum.size(), 64u);
}

TEST(MapFile, ADamagedCutShortOrNewerFileIsRefusedSayingWhy) {
  const std::string good = EncodeMapFile(Saved(FlightMap()));
  ASSERT_EQ(RefusalOf(good), "");
  std::string damaged = good;
  damaged[good.size() / 2] ^= 0x10;
  EXPECT_NE(RefusalOf(damaged).find("checksum does not match"), std::string::npos) << RefusalOf(damaged);
  EXPECT_NE(RefusalOf(good.substr(0, good.size() - 7)).find("cut short"), std::string::npos);
  EXPECT_NE(RefusalOf(good.substr(0, 20)).find("not a stitch map"), std::string::npos);
  EXPECT_NE(RefusalOf("ply\nformat ascii 1.0\n").find("not a stitch map"), std::string::npos);
  std::string newer = good;
  newer[8] = 2;
  EXPECT_NE(RefusalOf(newer).find("format version 2; this stitch reads version 1 only"), std::string::npos)
      << RefusalOf(newer);
  // A count that would take more bytes than the file holds is refused before anything is made.
  std::string huge = good;
  for (int i = 0; i < 4; ++i) huge[56 + i] = static_cast<char>(0xff);
  Reseal(&huge);
  EXPECT_NE(RefusalOf(huge).find("cut short in the description"), std::string::npos) << RefusalOf(huge);
  EXPECT_THROW(ReadMapFile("/nonexistent/site.stitchmap", kSaved), Error);
}

// A resealed file with any byte changed (a hostile or buggy writer) is read or refused, never
// misread into an inconsistent map (the sanitizers watch this test).
TEST(MapFile, ABitFlippedAndResealedFileIsReadOrRefusedNeverMisread) {
  const std::string good = EncodeMapFile(Saved(FlightMap()));
  std::mt19937 rng(7);
  int refused = 0;
  for (int trial = 0; trial < 1500; ++trial) {
    std::string bytes = good;
    const size_t at = 56 + rng() % (good.size() - 56);
    bytes[at] = static_cast<char>(bytes[at] ^ (1u << (rng() % 8)));
    Reseal(&bytes);
    try {
      const SavedMap read = DecodeMapFile(bytes, kSaved);
      for (const auto& [id, keyframe] : read.map.keyframes()) {
        for (MapPointId p : keyframe.points) {
          if (p.valid()) {
            ASSERT_NE(read.map.FindPoint(p), nullptr);
          }
        }
        ASSERT_LT(read.camera_index.at(id), static_cast<int>(read.cameras.size()));
      }
    } catch (const Error&) {
      ++refused;
    }
  }
  EXPECT_GT(refused, 0);
}

}  // namespace
}  // namespace stitch
