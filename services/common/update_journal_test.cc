#include "services/common/update_journal.h"

#include <filesystem>

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
