#include "services/common/update_journal.h"

#include <filesystem>
#include <fstream>

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

TEST(UpdateJournal, ARecordCutShortByAKillIsDroppedAndTheJournalGoesOn) {
  testing::TempDir dir;
  std::string path;
  {
    UpdateJournal journal(dir.path().string(), {"uav0/SUBMAP"});
    Revisions(&journal);
    for (int r = 1; r <= 4; ++r) journal.Append(Update(r));
    path = journal.path();
  }
  // The process died while writing the fourth record.
  std::filesystem::resize_file(path, std::filesystem::file_size(path) - 7);
  {
    UpdateJournal journal(dir.path().string(), {"uav0/SUBMAP"});
    EXPECT_EQ(Revisions(&journal), (std::vector<int>{1, 2, 3}));
    journal.Append(Update(5));
  }
  UpdateJournal again(dir.path().string(), {"uav0/SUBMAP"});
  EXPECT_EQ(Revisions(&again), (std::vector<int>{1, 2, 3, 5}));
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
