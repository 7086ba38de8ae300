// Every output file stitch writes reports a full disk naming the file, and leaves no cut file
// behind: a trajectory, a point cloud, a plot.

#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>

#include <gtest/gtest.h>

#include "stitch/io/image_file.h"
#include "stitch/io/output_frames.h"
#include "stitch/io/ply.h"
#include "stitch/io/trajectory.h"
#include "stitch/testing/full_disk.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

// Writes `path` with a disk that is full after 64 bytes: an Error naming the file, and no file.
void ExpectFullDiskNamed(const std::string& path, const std::function<void()>& write) {
  try {
    const testing::FullDiskAfter full(64);
    write();
    FAIL() << path << ": no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
  }
  EXPECT_FALSE(std::filesystem::exists(path));
  EXPECT_FALSE(std::filesystem::exists(path + ".partial"));
}

TEST(OutputFiles, AFullDiskIsAnErrorNamingTheFile) {
  testing::TempDir dir;
  Trajectory trajectory;
  for (int i = 0; i < 10; ++i) trajectory.Add({int64_t{1'000'000'000} * i, Rigid3d()});
  ExpectFullDiskNamed(dir / "trajectory.tum", [&] { trajectory.WriteTum(dir / "trajectory.tum"); });
  const std::vector<ColouredPoint> points(100, ColouredPoint{Eigen::Vector3f(1, 2, 3)});
  ExpectFullDiskNamed(dir / "map.ply", [&] { WritePly(dir / "map.ply", points); });
  const cv::Mat plot(64, 64, CV_8UC3, cv::Scalar(10, 200, 30));
  ExpectFullDiskNamed(dir / "trajectory.png", [&] { WritePng(dir / "trajectory.png", plot); });
  // With room, each is written whole.
  trajectory.WriteTum(dir / "trajectory.tum");
  EXPECT_EQ(Trajectory::ReadTum(dir / "trajectory.tum").size(), 10u);
  WritePly(dir / "map.ply", points);
  EXPECT_EQ(ReadPly(dir / "map.ply").size(), 100u);
  WritePng(dir / "trajectory.png", plot);
  EXPECT_GT(std::filesystem::file_size(dir / "trajectory.png"), 0u);
}

// Each trajectory and point cloud says its frame and units in its header, where the readers of
// the formats (TUM's tools, evo, MeshLab, CloudCompare, ours) take it as a comment.
TEST(OutputFiles, TrajectoriesAndCloudsStateTheirFrameInTheirHeaders) {
  testing::TempDir dir;
  Trajectory trajectory;
  for (int i = 0; i < 3; ++i) trajectory.Add({int64_t{1'000'000'000} * i, Rigid3d()});
  trajectory.WriteTum(dir / "trajectory.tum", output_frames::kLargestMap);
  EXPECT_EQ(Trajectory::ReadTum(dir / "trajectory.tum").size(), 3u);
  std::ifstream tum(dir / "trajectory.tum");
  std::string first, second;
  std::getline(tum, first);
  std::getline(tum, second);
  EXPECT_NE(first.find("world_from_cam; seconds"), std::string::npos) << first;
  EXPECT_EQ(second, std::string("# frame: ") + output_frames::kLargestMap);
  WritePly(dir / "map.ply", {ColouredPoint{Eigen::Vector3f(1, 2, 3)}}, output_frames::kLargestMap);
  EXPECT_EQ(ReadPly(dir / "map.ply").size(), 1u);
  std::ifstream ply(dir / "map.ply", std::ios::binary);
  std::string header((std::istreambuf_iterator<char>(ply)), std::istreambuf_iterator<char>());
  header = header.substr(0, header.find("end_header"));
  EXPECT_NE(header.find(std::string("comment frame: ") + output_frames::kLargestMap + "\n"), std::string::npos)
      << header;
}

}  // namespace
}  // namespace stitch
