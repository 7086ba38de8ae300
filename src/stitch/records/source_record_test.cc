#include "stitch/records/source_record.h"

#include <fstream>

#include <gtest/gtest.h>

#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

TEST(SourceRecord, ReadsBackAsWrittenAndRefusesWhatIsNone) {
  testing::TempDir dir;
  const std::string path = dir / "ingest.json";
  SourceRecord record;
  record.frames_published = 450;
  record.frames_late = 12;
  record.most_late_s = 0.25;
  record.seconds = 15.5;
  WriteSourceRecord(path, record);
  const SourceRecord read = ReadSourceRecord(path);
  EXPECT_EQ(read.frames_published, 450);
  EXPECT_EQ(read.frames_late, 12);
  EXPECT_DOUBLE_EQ(read.most_late_s, 0.25);
  EXPECT_DOUBLE_EQ(read.seconds, 15.5);

  EXPECT_THROW(ReadSourceRecord(dir / "absent.json"), Error);
  std::ofstream(path, std::ios::trunc) << "{\"frames_published\": 3";
  EXPECT_THROW(ReadSourceRecord(path), Error);
  std::ofstream(path, std::ios::trunc)
      << R"({"frames_published": 3, "frames_late": 4, "most_late_s": 0, "seconds": 1})";
  EXPECT_THROW(ReadSourceRecord(path), Error);
}

}  // namespace
}  // namespace stitch
