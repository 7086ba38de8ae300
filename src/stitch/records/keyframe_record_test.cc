#include "stitch/records/keyframe_record.h"

#include <fstream>

#include <gtest/gtest.h>

#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

TEST(KeyframeRecord, RoundTripsThroughTheFile) {
  testing::TempDir dir;
  const std::string path = dir / "keyframes.tsv";
  const KeyframeRecord kept{4294967297, 4294967296,
                            12,         600'000'000,
                            false,      Rigid3d(Eigen::Quaterniond(0.6, 0, 0.8, 0), Eigen::Vector3d(1.5, -2, 10))};
  KeyframeRecord culled = kept;
  culled.keyframe_id = 4294967298;
  culled.culled = true;
  WriteKeyframeRecords(path, {kept, culled});
  const std::vector<KeyframeRecord> records = ReadKeyframeRecords(path);
  ASSERT_EQ(records.size(), 2u);
  EXPECT_EQ(records[0].keyframe_id, kept.keyframe_id);
  EXPECT_EQ(records[0].submap_id, kept.submap_id);
  EXPECT_EQ(records[0].frame_index, 12);
  EXPECT_EQ(records[0].t_ns, 600'000'000);
  EXPECT_FALSE(records[0].culled);
  EXPECT_TRUE(records[1].culled);
  EXPECT_LT((records[0].world_from_cam.translation - kept.world_from_cam.translation).norm(), 1e-6);
  EXPECT_LT(records[0].world_from_cam.rotation.angularDistance(kept.world_from_cam.rotation), 1e-6);
}

TEST(KeyframeRecord, AMalformedLineIsNamed) {
  testing::TempDir dir;
  const std::string path = dir / "keyframes.tsv";
  std::ofstream(path) << KeyframeRecordHeader() << "4294967297 4294967296 12 600000000 0 1.5 -2\n";
  try {
    ReadKeyframeRecords(path);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("keyframes.tsv:2"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace stitch
