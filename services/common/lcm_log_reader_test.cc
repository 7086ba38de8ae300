#include "services/common/lcm_log_reader.h"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <random>
#include <set>

#include <gtest/gtest.h>
#include <lcm/lcm-cpp.hpp>

#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

struct Written {
  std::string channel;
  std::vector<uint8_t> data;
  int64_t offset = 0, end = 0;
};

// Writes `count` records with liblcm's writer (payloads of 100-2000 bytes that never hold the
// sync word); returns them with their place in the file.
std::vector<Written> WriteLog(const std::string& path, int count, uint32_t seed = 1) {
  std::mt19937 random(seed);
  std::vector<Written> written;
  lcm::LogFile log(path, "w");
  for (int i = 0; i < count; ++i) {
    Written w;
    w.channel = i % 3 == 0 ? "uav0/SUBMAP" : "uav0/TRACKING_STATUS";
    w.data.resize(100 + random() % 1900);
    for (uint8_t& b : w.data) b = static_cast<uint8_t>(random() % 200);  // never 0xED or 0xDA
    lcm::LogEvent event;
    event.eventnum = i;
    event.timestamp = 1000 + i;
    event.channel = w.channel;
    event.datalen = static_cast<int32_t>(w.data.size());
    event.data = w.data.data();
    EXPECT_EQ(log.writeEvent(&event), 0);
    std::fflush(log.getFilePtr());
    w.end = static_cast<int64_t>(std::ftell(log.getFilePtr()));
    w.offset = w.end - 28 - static_cast<int64_t>(w.channel.size() + w.data.size());
    written.push_back(std::move(w));
  }
  return written;
}

void Overwrite(const std::string& path, int64_t offset, const std::vector<uint8_t>& bytes) {
  std::fstream file(path, std::ios::binary | std::ios::in | std::ios::out);
  file.seekp(offset);
  file.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
}

std::vector<LcmLogRecord> ReadAll(LcmLogReader* reader) {
  std::vector<LcmLogRecord> records;
  while (auto record = reader->Next()) records.push_back(std::move(*record));
  return records;
}

TEST(LcmLogReader, ReadsWhatLiblcmWroteByteForByte) {
  testing::TempDir dir;
  const std::string path = (dir / "a.lcmlog");
  const std::vector<Written> written = WriteLog(path, 6);
  LcmLogReader reader(path);
  const std::vector<LcmLogRecord> records = ReadAll(&reader);
  ASSERT_EQ(records.size(), written.size());
  for (size_t i = 0; i < records.size(); ++i) {
    EXPECT_EQ(records[i].channel, written[i].channel);
    EXPECT_EQ(records[i].data, written[i].data);
    EXPECT_EQ(records[i].event_number, static_cast<int64_t>(i));
    EXPECT_EQ(records[i].utime, 1000 + static_cast<int64_t>(i));
    EXPECT_EQ(records[i].offset, written[i].offset);
    EXPECT_EQ(records[i].end, written[i].end);
  }
  EXPECT_TRUE(reader.damage().empty());
}

TEST(LcmLogReader, FourZeroedBytesCostOnlyTheRecordTheyHit) {
  testing::TempDir dir;
  const std::string path = (dir / "a.lcmlog");
  const std::vector<Written> written = WriteLog(path, 8);
  Overwrite(path, written[3].offset + 2, {0, 0, 0, 0});  // in the sync word and event number
  LcmLogReader reader(path);
  const std::vector<LcmLogRecord> records = ReadAll(&reader);
  ASSERT_EQ(records.size(), 7u);
  EXPECT_EQ(records[3].offset, written[4].offset);
  EXPECT_EQ(records.back().data, written.back().data);
  ASSERT_EQ(reader.damage().size(), 1u);
  EXPECT_EQ(reader.damage()[0].offset, written[3].offset);
  EXPECT_EQ(reader.damage()[0].length, written[3].end - written[3].offset);
}

TEST(LcmLogReader, ALengthOfTwoGigabytesIsNeitherTrustedNorAllocated) {
  testing::TempDir dir;
  const std::string path = (dir / "a.lcmlog");
  const std::vector<Written> written = WriteLog(path, 5);
  Overwrite(path, written[1].offset + 24, {0x7f, 0xff, 0xff, 0xff});  // its data length
  LcmLogReader reader(path);
  const std::vector<LcmLogRecord> records = ReadAll(&reader);
  ASSERT_EQ(records.size(), 4u);
  EXPECT_EQ(records[1].data, written[2].data);
  EXPECT_EQ(DamagedBytes(reader.damage()), written[1].end - written[1].offset);
}

TEST(LcmLogReader, ALengthThatRunsIntoTheNextRecordsIsCaught) {
  testing::TempDir dir;
  const std::string path = (dir / "a.lcmlog");
  const std::vector<Written> written = WriteLog(path, 5);
  // Record 1's data length now ends inside record 3: within the file, but no sync word follows.
  const int64_t claimed =
      written[3].offset + 40 - written[1].offset - 28 - static_cast<int64_t>(written[1].channel.size());
  Overwrite(path, written[1].offset + 24,
            {static_cast<uint8_t>(claimed >> 24), static_cast<uint8_t>(claimed >> 16),
             static_cast<uint8_t>(claimed >> 8), static_cast<uint8_t>(claimed)});
  LcmLogReader reader(path);
  const std::vector<LcmLogRecord> records = ReadAll(&reader);
  ASSERT_EQ(records.size(), 4u);
  EXPECT_EQ(records[1].offset, written[2].offset);
  EXPECT_EQ(records[3].data, written[4].data);
}

TEST(LcmLogReader, ARecordCutShortAtTheEndIsDamageAndItsPredecessorIsWhole) {
  testing::TempDir dir;
  const std::string path = (dir / "a.lcmlog");
  const std::vector<Written> written = WriteLog(path, 4);
  for (int64_t cut : {written[3].end - written[3].offset - 1, int64_t{20}, int64_t{2}}) {  // shorter and shorter
    std::filesystem::resize_file(path, static_cast<uintmax_t>(written[3].offset + cut));
    LcmLogReader reader(path);
    EXPECT_EQ(ReadAll(&reader).size(), 3u) << "cut after " << cut << " bytes of the last record";
    ASSERT_EQ(reader.damage().size(), 1u);
    EXPECT_EQ(reader.damage()[0].offset, written[3].offset);
  }
}

TEST(LcmLogReader, AFileThatIsNoLogIsAllDamageAndAMissingOneIsAnError) {
  testing::TempDir dir;
  const std::string path = (dir / "noise");
  std::ofstream(path) << std::string(5000, 'x');
  LcmLogReader reader(path);
  EXPECT_TRUE(ReadAll(&reader).empty());
  EXPECT_EQ(DamagedBytes(reader.damage()), 5000);
  EXPECT_THROW(LcmLogReader((dir / "absent")), Error);
}

// A corpus of damaged logs: stretches overwritten with zeros, random bytes or 0xff, single bit
// flips, lengths rewritten, the file cut. Whatever the damage, the reader does not crash, every
// record it returns is one that was written, in place, the records and the damaged stretches
// tile the file, and every record the damage did not touch (nor the 4 bytes after it) is read.
TEST(LcmLogReader, DamagedLogsGiveBackEveryIntactRecord) {
  testing::TempDir dir;
  const std::string path = (dir / "a.lcmlog");
  for (uint32_t seed = 1; seed <= 300; ++seed) {
    const std::vector<Written> written = WriteLog(path, 20, seed);
    const int64_t size = written.back().end;
    std::mt19937 random(seed);
    std::vector<bool> touched(static_cast<size_t>(size), false);
    const int damages = 1 + static_cast<int>(random() % 4);
    for (int d = 0; d < damages; ++d) {
      const int kind = static_cast<int>(random() % 4);
      int64_t offset = static_cast<int64_t>(random() % static_cast<uint32_t>(size));
      int64_t length = kind == 3 ? 4 : 1 + static_cast<int64_t>(random() % 64);
      if (kind == 3) {  // a length field of some record
        const Written& w = written[random() % written.size()];
        offset = w.offset + (random() % 2 ? 20 : 24);
      }
      length = std::min(length, size - offset);
      std::vector<uint8_t> bytes(static_cast<size_t>(length));
      for (uint8_t& b : bytes) b = kind == 0 ? 0 : kind == 1 ? static_cast<uint8_t>(random()) : 0xff;
      if (kind == 3) bytes = {static_cast<uint8_t>(random()), static_cast<uint8_t>(random()), 0, 0};
      Overwrite(path, offset, bytes);
      for (int64_t i = offset; i < offset + length; ++i) touched[static_cast<size_t>(i)] = true;
    }
    int64_t end = size;
    if (random() % 4 == 0) {
      end = static_cast<int64_t>(random() % static_cast<uint32_t>(size));
      std::filesystem::resize_file(path, static_cast<uintmax_t>(end));
    }
    LcmLogReader reader(path);
    const std::vector<LcmLogRecord> records = ReadAll(&reader);
    int64_t covered = DamagedBytes(reader.damage());
    std::set<int64_t> offsets;
    for (const LcmLogRecord& r : records) {
      covered += r.end - r.offset;
      offsets.insert(r.offset);
      const bool written_there =
          std::any_of(written.begin(), written.end(), [&](const Written& w) { return w.offset == r.offset; });
      EXPECT_TRUE(written_there) << "seed " << seed << ": a record at offset " << r.offset << " was never written";
    }
    EXPECT_EQ(covered, end) << "seed " << seed;
    for (const Written& w : written) {
      const int64_t checked_end = std::min(w.end + 4, size);
      if (checked_end > end) continue;  // cut off
      bool intact = true;
      for (int64_t i = w.offset; i < checked_end; ++i) intact = intact && !touched[static_cast<size_t>(i)];
      if (!intact) continue;
      EXPECT_TRUE(offsets.count(w.offset)) << "seed " << seed << ": the intact record at " << w.offset << " was lost";
    }
  }
}

TEST(SetDamageAside, KeepsTheWholeRecordsAndMovesTheDamagedBytesAside) {
  testing::TempDir dir;
  const std::string path = (dir / "a.lcmlog"), aside = (dir / "a.lcmlog.damaged");
  const std::vector<Written> written = WriteLog(path, 6);
  Overwrite(path, written[2].offset, {0, 0, 0, 0});
  std::filesystem::resize_file(path, static_cast<uintmax_t>(written[5].offset + 10));
  std::vector<LcmLogDamage> damage;
  {
    LcmLogReader reader(path);
    ReadAll(&reader);
    damage = reader.damage();
  }
  ASSERT_EQ(damage.size(), 2u);
  SetDamageAside(path, damage, aside);
  EXPECT_EQ(static_cast<int64_t>(std::filesystem::file_size(aside)), damage[0].length + damage[1].length);
  LcmLogReader reader(path);
  const std::vector<LcmLogRecord> records = ReadAll(&reader);
  EXPECT_TRUE(reader.damage().empty());
  ASSERT_EQ(records.size(), 4u);
  EXPECT_EQ(records[2].data, written[3].data);
  EXPECT_EQ(records[3].data, written[4].data);
}

}  // namespace
}  // namespace stitch
