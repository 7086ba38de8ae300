#include "stitch/util/text_file.h"

#include <filesystem>
#include <fstream>
#include <sstream>

#include <gtest/gtest.h>

#include "stitch/testing/full_disk.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

std::string Contents(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

TEST(WriteFileAtomically, ReplacesTheFileWhole) {
  testing::TempDir dir;
  const std::string path = dir / "report.json";
  WriteFileAtomically(path, "first\n");
  WriteFileAtomically(path, "second\n");
  EXPECT_EQ(Contents(path), "second\n");
  EXPECT_FALSE(std::filesystem::exists(path + ".partial"));
}

// A full disk: the error names the file and says why, the old file stays as it was, and no
// partial file is left beside it.
TEST(WriteFileAtomically, AFullDiskIsAnErrorNamingTheFileAndKeepsTheOldOne) {
  testing::TempDir dir;
  const std::string path = dir / "trajectory.tum";
  WriteFileAtomically(path, "old\n");
  try {
    const testing::FullDiskAfter full(100);
    WriteFileAtomically(path, std::string(1000, 'x'));  // inside one stdio buffer: fails at close
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(path + ": write failed"), std::string::npos) << e.what();
  }
  EXPECT_EQ(Contents(path), "old\n");
  EXPECT_FALSE(std::filesystem::exists(path + ".partial"));
}

TEST(WriteFileAtomically, AFolderThatIsNotThereIsAnErrorNamingTheFile) {
  try {
    WriteFileAtomically("/nonexistent-folder/report.json", "x");
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent-folder/report.json: cannot write"), std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace stitch
