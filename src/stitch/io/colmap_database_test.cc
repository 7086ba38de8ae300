#include "stitch/io/colmap_database.h"

#include <sqlite3.h>

#include <cstring>
#include <filesystem>
#include <map>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Geometry>

#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

// Three images of four points: points 1-3 seen by images 1 and 2, point 4 by all three; image 3
// from a second camera.
ColmapModel ThreeViews() {
  ColmapModel model;
  model.cameras.emplace(1, Camera::Pinhole(640, 480, 450, 451, 319.5, 239.5, 0.1, -0.05));
  model.cameras.emplace(2, Camera::Pinhole(752, 480, 458, 457, 367, 248));
  const std::vector<Eigen::Vector3d> points = {{0, 0, 5}, {1, -0.5, 6}, {-1, 0.7, 4}, {0.3, 0.2, 5.5}};
  const std::vector<std::vector<int>> seen_by = {{1, 2}, {1, 2}, {1, 2}, {1, 2, 3}};
  for (int i = 0; i < 3; ++i) {
    ColmapImage image;
    image.id = i + 1;
    image.camera_id = i < 2 ? 1 : 2;
    image.name = "rgb/" + std::to_string(i) + ".png";
    image.cam_from_world = Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.1 * i, Eigen::Vector3d::UnitY())),
                                   Eigen::Vector3d(-0.5 * i, 0.1 * i, 0));
    image.features.emplace_back(10, 10);  // a feature of no point first
    image.point_ids.push_back(-1);
    model.images.push_back(image);
  }
  for (size_t p = 0; p < points.size(); ++p) {
    ColmapPoint point;
    point.id = static_cast<int64_t>(p) + 1;
    point.position = points[p];
    for (int image_id : seen_by[p]) {
      ColmapImage& image = model.images[image_id - 1];
      image.features.push_back(*model.cameras.at(image.camera_id).Project(image.cam_from_world * points[p]));
      image.point_ids.push_back(point.id);
      point.track.push_back({image_id, static_cast<int>(image.features.size()) - 1});
    }
    model.points.push_back(point);
  }
  return model;
}

// The rows of one query, each column as a double or a blob's bytes.
struct Row {
  std::vector<double> numbers;
  std::vector<std::vector<char>> blobs;
};
std::vector<Row> Query(const std::string& path, const std::string& sql) {
  sqlite3* db = nullptr;
  EXPECT_EQ(sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr), SQLITE_OK);
  sqlite3_stmt* statement = nullptr;
  EXPECT_EQ(sqlite3_prepare_v2(db, sql.c_str(), -1, &statement, nullptr), SQLITE_OK) << sqlite3_errmsg(db);
  std::vector<Row> rows;
  while (sqlite3_step(statement) == SQLITE_ROW) {
    Row row;
    for (int c = 0; c < sqlite3_column_count(statement); ++c) {
      if (sqlite3_column_type(statement, c) == SQLITE_BLOB) {
        const char* bytes = static_cast<const char*>(sqlite3_column_blob(statement, c));
        row.blobs.emplace_back(bytes, bytes + sqlite3_column_bytes(statement, c));
      } else {
        row.numbers.push_back(sqlite3_column_double(statement, c));
      }
    }
    rows.push_back(std::move(row));
  }
  sqlite3_finalize(statement);
  sqlite3_close(db);
  return rows;
}

template <class T>
std::vector<T> As(const std::vector<char>& blob) {
  std::vector<T> values(blob.size() / sizeof(T));
  std::memcpy(values.data(), blob.data(), values.size() * sizeof(T));
  return values;
}

TEST(ColmapDatabase, HoldsTheCamerasImagesKeypointsAndTheMapsMatches) {
  testing::TempDir dir;
  const ColmapModel model = ThreeViews();
  const std::string path = dir / "database.db";
  const ColmapDatabaseSummary summary = WriteColmapDatabase(model, path);
  EXPECT_EQ(summary.cameras, 2);
  EXPECT_EQ(summary.images, 3);
  EXPECT_EQ(summary.keypoints, 5 + 5 + 2);
  EXPECT_EQ(summary.image_pairs, 3);  // (1,2) four points, (1,3) and (2,3) one
  EXPECT_EQ(summary.matches, 4 + 1 + 1);

  // Cameras: COLMAP's OPENCV (4) with the principal point in its pixel convention, PINHOLE (1).
  const auto cameras = Query(path, "SELECT camera_id, model, width, height, prior_focal_length, params FROM cameras");
  ASSERT_EQ(cameras.size(), 2u);
  EXPECT_EQ(cameras[0].numbers, (std::vector<double>{1, 4, 640, 480, 1}));
  EXPECT_EQ(As<double>(cameras[0].blobs[0]), (std::vector<double>{450, 451, 320, 240, 0.1, -0.05, 0, 0}));
  EXPECT_EQ(cameras[1].numbers, (std::vector<double>{2, 1, 752, 480, 1}));

  // Images with their cameras and the SLAM pose as the prior.
  const auto images = Query(path, "SELECT image_id, camera_id, prior_qw, prior_tx FROM images ORDER BY image_id");
  ASSERT_EQ(images.size(), 3u);
  EXPECT_EQ(images[2].numbers[1], 2);
  EXPECT_NEAR(images[2].numbers[2], model.images[2].cam_from_world.rotation.w(), 1e-12);
  EXPECT_NEAR(images[2].numbers[3], -1.0, 1e-12);

  // Keypoints in COLMAP's pixel convention.
  const auto keypoints = Query(path, "SELECT rows, cols, data FROM keypoints WHERE image_id = 1");
  ASSERT_EQ(keypoints.size(), 1u);
  EXPECT_EQ(keypoints[0].numbers, (std::vector<double>{5, 2}));
  const std::vector<float> xy = As<float>(keypoints[0].blobs[0]);
  ASSERT_EQ(xy.size(), 10u);
  EXPECT_FLOAT_EQ(xy[0], 10.5f);
  EXPECT_NEAR(xy[2], model.images[0].features[1].x() + 0.5, 1e-4);

  // The pair (1, 3): feature 4 of image 1 (point 4) and feature 1 of image 3; verified with an
  // essential matrix that the pair's points satisfy.
  const int64_t pair_id = 1 * 2147483647LL + 3;
  const auto matches = Query(path, "SELECT rows, data FROM matches WHERE pair_id = " + std::to_string(pair_id));
  ASSERT_EQ(matches.size(), 1u);
  EXPECT_EQ(As<uint32_t>(matches[0].blobs[0]), (std::vector<uint32_t>{4, 1}));
  const auto geometry = Query(path, "SELECT rows, config, data, E FROM two_view_geometries WHERE pair_id = " +
                                        std::to_string(1 * 2147483647LL + 2));
  ASSERT_EQ(geometry.size(), 1u);
  EXPECT_EQ(geometry[0].numbers, (std::vector<double>{4, 2}));  // four matches, CALIBRATED
  const std::vector<double> e = As<double>(geometry[0].blobs[1]);
  ASSERT_EQ(e.size(), 9u);
  const Eigen::Map<const Eigen::Matrix3d> essential(e.data());  // column-major, as Eigen's own
  for (int p = 0; p < 4; ++p) {
    const Eigen::Vector3d x1 = model.images[0].cam_from_world * model.points[p].position;
    const Eigen::Vector3d x2 = model.images[1].cam_from_world * model.points[p].position;
    EXPECT_NEAR(x2.normalized().dot(essential * x1.normalized()), 0, 1e-9) << "point " << p + 1;
  }

  // A database is never written over.
  EXPECT_THROW(WriteColmapDatabase(model, path), Error);
  // An image of a camera the model lacks is refused, and no half-written file stays.
  ColmapModel broken = model;
  broken.images[1].camera_id = 9;
  EXPECT_THROW(WriteColmapDatabase(broken, dir / "broken.db"), Error);
  EXPECT_FALSE(std::filesystem::exists(dir / "broken.db"));
}

}  // namespace
}  // namespace stitch
