#include "services/common/update_journal.h"

#include <filesystem>
#include <fstream>
#include <thread>

#include <gtest/gtest.h>

#include "stitch/testing/temp_dir.h"

namespace stitch {
namespace {

stitch::submap_update_t Update(int revision, const std::string& agent = "uav0") {
  stitch::submap_update_t update{};
  update.header.agent = agent;
  update.submap_id = 1LL << 32;
  update.revision = revision;
  update.num_parts = 1;
  return update;
}

std::vector<int> Revisions(UpdateJournal* journal) {
  std::vector<int> revisions;
  journal->Recover([&](const stitch::submap_update_t& u) { revisions.push_back(u.revision); });
  return revisions;
}

TEST(UpdateJournal, WhatWasAppendedComesBackInOrderAfterARestart) {
  testing::TempDir dir;
  {
    UpdateJournal journal(dir.path().string(), {"uav0/SUBMAP"});
    EXPECT_TRUE(Revisions(&journal).empty());
    for (int r = 1; r <= 3; ++r) journal.Append(Update(r));
  }
  UpdateJournal again(dir.path().string(), {"uav0/SUBMAP"});
  EXPECT_EQ(Revisions(&again), (std::vector<int>{1, 2, 3}));
}

// The aircraft's GNSS fixes are kept with the updates, in their place among them, and only for
// a reader that asks for them.
TEST(UpdateJournal, GnssFixesComeBackInTheirPlaceAmongTheUpdates) {
  testing::TempDir dir;
  {
    UpdateJournal journal(dir.path().string(), {"uav0/SUBMAP"});
    Revisions(&journal);
    journal.Append(Update(1));
    stitch::gnss_fix_t fix{};
    fix.header.agent = "uav0";
    fix.t_ns = 5'000'000'000;
    fix.latitude_deg = 48.1;
    journal.Append(fix);
    fix.header.agent = "uav1";  // not an aircraft of this journal
    journal.Append(fix);
    journal.Append(Update(2));
    EXPECT_EQ(journal.appended(), 4);
  }
  UpdateJournal again(dir.path().string(), {"uav0/SUBMAP"});
  std::vector<std::string> order;
  again.Recover([&](const stitch::submap_update_t& u) { order.push_back("update " + std::to_string(u.revision)); },
                [&](const stitch::gnss_fix_t& f) {
                  order.push_back("fix " + f.header.agent + " " + std::to_string(f.t_ns / 1'000'000'000));
                });
  EXPECT_EQ(order, (std::vector<std::string>{"update 1", "fix uav0 5", "update 2"}));
  const SubmapUpdateLogRead without = ReadSubmapUpdateLog(again.path(), {"uav0/SUBMAP"}, [](const auto&) {});
  EXPECT_EQ(without.updates, 2);
  EXPECT_EQ(without.gnss_fixes, 0);
  EXPECT_FALSE(without.lost_anything());
}

// The merger appends fixes from its subscriber's thread while its worker appends updates.
TEST(UpdateJournal, FixesAndUpdatesAppendedFromTwoThreadsAreAllKeptWhole) {
  testing::TempDir dir;
  constexpr int kEach = 200;
  {
    UpdateJournal journal(dir.path().string(), {"uav0/SUBMAP"});
    Revisions(&journal);
    std::thread fixes([&] {
      stitch::gnss_fix_t fix{};
      fix.header.agent = "uav0";
      for (int i = 0; i < kEach; ++i) {
        fix.t_ns = i;
        journal.Append(fix);
      }
    });
    for (int r = 0; r < kEach; ++r) journal.Append(Update(r));
    fixes.join();
    EXPECT_EQ(journal.appended(), 2 * kEach);
  }
  int updates = 0, fixes = 0;
  const SubmapUpdateLogRead read = ReadSubmapUpdateLog(
      dir / "submap_updates.lcmlog", {"uav0/SUBMAP"}, [&](const auto&) { ++updates; },
      [&](const stitch::gnss_fix_t& fix) { fixes += fix.t_ns == fixes; });
  EXPECT_EQ(updates, kEach);
  EXPECT_EQ(fixes, kEach) << "each fix once, in order";
  EXPECT_EQ(read.unchecked, 0);
  EXPECT_FALSE(read.lost_anything());
}

// A journal in `dir` holding revisions 1..last; where each record starts, and the journal's path.
std::vector<int64_t> JournalOfRevisions(const testing::TempDir& dir, int last, std::string* path) {
  UpdateJournal journal(dir.path().string(), {"uav0/SUBMAP"});
  Revisions(&journal);
  std::vector<int64_t> offsets;
  for (int r = 1; r <= last; ++r) {
    offsets.push_back(static_cast<int64_t>(std::filesystem::file_size(journal.path())));
    journal.Append(Update(r));
  }
  *path = journal.path();
  return offsets;
}

TEST(UpdateJournal, ARecordCutShortByAKillIsDroppedAndTheJournalGoesOn) {
  testing::TempDir dir;
  std::string path;
  const std::vector<int64_t> offsets = JournalOfRevisions(dir, 4, &path);
  // The process died while writing the fourth record.
  std::filesystem::resize_file(path, static_cast<uintmax_t>(offsets[3] + 40));
  {
    UpdateJournal journal(dir.path().string(), {"uav0/SUBMAP"});
    EXPECT_EQ(Revisions(&journal), (std::vector<int>{1, 2, 3}));
    journal.Append(Update(5));
  }
  {
    UpdateJournal again(dir.path().string(), {"uav0/SUBMAP"});
    EXPECT_EQ(Revisions(&again), (std::vector<int>{1, 2, 3, 5}));
    again.Append(Update(6));
  }
  // Killed between an update and its checksum: the update is whole, and read unchecked.
  std::filesystem::resize_file(path, std::filesystem::file_size(path) - 7);
  const SubmapUpdateLogRead read = ReadSubmapUpdateLog(path, {"uav0/SUBMAP"}, [](const auto&) {});
  EXPECT_EQ(read.updates, 5);
  EXPECT_EQ(read.unchecked, 1);
  UpdateJournal last(dir.path().string(), {"uav0/SUBMAP"});
  EXPECT_EQ(Revisions(&last), (std::vector<int>{1, 2, 3, 5, 6}));
}

void Overwrite(const std::string& path, int64_t offset, const std::string& bytes) {
  std::fstream file(path, std::ios::binary | std::ios::in | std::ios::out);
  file.seekp(offset);
  file.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// The security issue's row: 4 zeroed bytes mid-file made the restarted merger delete the intact
// second half as "a record left unfinished".
TEST(UpdateJournal, FourZeroedBytesMidFileCostOneRecordAndEveryRecordAfterThemIsKept) {
  testing::TempDir dir;
  std::string path;
  const std::vector<int64_t> offsets = JournalOfRevisions(dir, 8, &path);
  const auto size = std::filesystem::file_size(path);
  Overwrite(path, offsets[3], std::string(4, '\0'));
  {
    UpdateJournal journal(dir.path().string(), {"uav0/SUBMAP"});
    EXPECT_EQ(Revisions(&journal), (std::vector<int>{1, 2, 3, 5, 6, 7, 8}));
    journal.Append(Update(9));
  }
  // The damaged record is set aside, not deleted; the journal goes on without it.
  const auto record = static_cast<uintmax_t>(offsets[4] - offsets[3]);
  EXPECT_EQ(std::filesystem::file_size(path + ".damaged"), record);
  EXPECT_EQ(std::filesystem::file_size(path), size);  // without record 4, with record 9 (the same size)
  UpdateJournal again(dir.path().string(), {"uav0/SUBMAP"});
  EXPECT_EQ(Revisions(&again), (std::vector<int>{1, 2, 3, 5, 6, 7, 8, 9}));
}

// The security issue's row: a length field set to 0x7fffffff crashed every start of the merger
// (and `stitch map`) in liblcm's reader.
TEST(UpdateJournal, ALengthFieldOfTwoGigabytesNeitherCrashesNorLosesTheOtherRecords) {
  testing::TempDir dir;
  std::string path;
  const std::vector<int64_t> offsets = JournalOfRevisions(dir, 5, &path);
  Overwrite(path, offsets[1] + 24, "\x7f\xff\xff\xff");
  UpdateJournal journal(dir.path().string(), {"uav0/SUBMAP"});
  EXPECT_EQ(Revisions(&journal), (std::vector<int>{1, 3, 4, 5}));
}

// The security issue's row: bit flips inside records that still decode changed the outputs
// without a word. A record whose bytes no longer match its checksum is set aside and counted.
TEST(UpdateJournal, ARecordDamagedInsideIsFoundByItsChecksumAndSetAside) {
  testing::TempDir dir;
  std::string path;
  const std::vector<int64_t> offsets = JournalOfRevisions(dir, 5, &path);
  // The third update's agent "uav0" becomes "uavX": it still decodes, as another aircraft's.
  std::ifstream in(path, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const size_t data = static_cast<size_t>(offsets[2]) + 28 + std::string("uav0/SUBMAP").size();
  const size_t agent = bytes.find("uav0", data);
  ASSERT_LT(agent, static_cast<size_t>(offsets[3]));
  Overwrite(path, static_cast<int64_t>(agent) + 3, "X");
  std::vector<std::string> agents;
  const SubmapUpdateLogRead read = ReadSubmapUpdateLog(path, {"uav0/SUBMAP"}, [&](const stitch::submap_update_t& u) {
    agents.push_back(u.header.agent + ":" + std::to_string(u.revision));
  });
  EXPECT_EQ(agents, (std::vector<std::string>{"uav0:1", "uav0:2", "uav0:4", "uav0:5"}));
  EXPECT_EQ(read.checksum_mismatches, 1);
  EXPECT_EQ(read.unchecked, 0);
  EXPECT_TRUE(read.lost_anything());
  // The merger sets the record and its checksum aside, and the journal goes on without them.
  UpdateJournal journal(dir.path().string(), {"uav0/SUBMAP"});
  EXPECT_EQ(Revisions(&journal), (std::vector<int>{1, 2, 4, 5}));
  EXPECT_EQ(std::filesystem::file_size(path + ".damaged"), static_cast<uintmax_t>(offsets[3] - offsets[2]));
  const SubmapUpdateLogRead again = ReadSubmapUpdateLog(path, {"uav0/SUBMAP"}, [](const auto&) {});
  EXPECT_EQ(again.updates, 4);
  EXPECT_FALSE(again.lost_anything());
}

// A recording without checksum records (lcm-logger's, or a journal written before them) is read
// whole, each update counted as unchecked.
TEST(UpdateJournal, ALogWithoutChecksumsIsReadUnchecked) {
  testing::TempDir dir;
  const std::string path = dir / "recording.lcmlog";
  {
    lcm::LogFile log(path, "w");
    for (int r = 1; r <= 3; ++r) {
      const stitch::submap_update_t update = Update(r);
      std::vector<uint8_t> bytes(static_cast<size_t>(update.getEncodedSize()));
      update.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
      lcm::LogEvent event;
      event.eventnum = r;
      event.timestamp = r;
      event.channel = "uav0/SUBMAP";
      event.datalen = static_cast<int32_t>(bytes.size());
      event.data = bytes.data();
      ASSERT_EQ(log.writeEvent(&event), 0);
    }
  }
  std::vector<int> revisions;
  const SubmapUpdateLogRead read = ReadSubmapUpdateLog(
      path, {"uav0/SUBMAP"}, [&](const stitch::submap_update_t& u) { revisions.push_back(u.revision); });
  EXPECT_EQ(revisions, (std::vector<int>{1, 2, 3}));
  EXPECT_EQ(read.unchecked, 3);
  EXPECT_EQ(read.checksum_mismatches, 0);
  EXPECT_FALSE(read.lost_anything());
}

TEST(UpdateJournal, OtherChannelsOfARecordingArePassedOver) {
  testing::TempDir dir;
  {
    UpdateJournal other(dir.path().string(), {"uav1/SUBMAP"});
    Revisions(&other);
    other.Append(Update(7, "uav1"));
  }
  UpdateJournal journal(dir.path().string(), {"uav0/SUBMAP"});
  EXPECT_TRUE(Revisions(&journal).empty());
}

}  // namespace
}  // namespace stitch
