#include "stitch/io/colmap_model.h"

#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

// Two images of three points, the features where the camera puts the points.
ColmapModel TwoViews(const Camera& camera) {
  ColmapModel model;
  model.cameras.emplace(1, camera);
  const std::vector<Eigen::Vector3d> points = {{0, 0, 5}, {1, -0.5, 6}, {-1, 0.7, 4}};
  for (int i = 0; i < 2; ++i) {
    ColmapImage image;
    image.id = i + 1;
    image.name = "rgb/" + std::to_string(i) + ".png";
    image.cam_from_world = Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.1 * i, Eigen::Vector3d::UnitY())),
                                   Eigen::Vector3d(-0.5 * i, 0, 0));
    for (size_t p = 0; p < points.size(); ++p) {
      image.features.push_back(*camera.Project(image.cam_from_world * points[p]));
      image.point_ids.push_back(static_cast<int64_t>(p) + 1);
    }
    image.features.emplace_back(10, 10);  // a feature of no point
    image.point_ids.push_back(-1);
    model.images.push_back(image);
  }
  for (size_t p = 0; p < points.size(); ++p) {
    ColmapPoint point;
    point.id = static_cast<int64_t>(p) + 1;
    point.position = points[p];
    point.rgb = {10, 20, static_cast<uint8_t>(30 + p)};
    point.track = {{1, static_cast<int>(p)}, {2, static_cast<int>(p)}};
    model.points.push_back(point);
  }
  return model;
}

TEST(ColmapModel, WritesAndReadsBackEveryCameraModel) {
  for (const Camera& camera :
       {Camera::Pinhole(640, 480, 450, 451, 319.5, 239.5), Camera::Pinhole(752, 480, 458, 457, 367, 248, -0.28, 0.07),
        Camera::Pinhole(640, 480, 517, 516, 318, 255, 0.26, -0.95, -0.005, 0.002, 1.16),
        Camera(CameraModel::kFisheye, 640, 480, {300, 300, 320, 240, 0.01, -0.02, 0.003, -0.001})}) {
    testing::TempDir dir;
    const ColmapModel model = TwoViews(camera);
    EXPECT_LT(ReprojectionRms(model), 1e-6) << camera.Describe();
    WriteColmapModel(model, dir / "sparse");
    const ColmapModel back = ReadColmapModel(dir / "sparse");
    ASSERT_EQ(back.cameras.size(), 1u);
    EXPECT_EQ(back.cameras.at(1).Describe(), camera.Describe());
    for (size_t k = 0; k < camera.params().size(); ++k) {
      EXPECT_NEAR(back.cameras.at(1).params()[k], camera.params()[k], 1e-9);
    }
    ASSERT_EQ(back.images.size(), 2u);
    EXPECT_EQ(back.images[1].name, "rgb/1.png");
    ASSERT_EQ(back.images[1].features.size(), 4u);
    EXPECT_NEAR((back.images[1].features[2] - model.images[1].features[2]).norm(), 0, 1e-9);
    EXPECT_EQ(back.images[1].point_ids[3], -1);
    ASSERT_EQ(back.points.size(), 3u);
    EXPECT_EQ(back.points[2].rgb[2], 32);
    EXPECT_EQ(back.points[2].track.size(), 2u);
    EXPECT_LT(ReprojectionRms(back), 1e-6) << camera.Describe();
  }
}

// A run that worked at a reduced size goes back to its images' size: the features where the
// resized camera puts the points, the reprojection still exact.
TEST(ColmapModel, AModelResizedToItsImagesKeepsItsPointsWhereTheCameraSeesThem) {
  const Camera working = Camera::Pinhole(942, 530, 662.3, 662.3, 470.5, 264.5, -0.05);
  const ColmapModel model = ResizeColmapModel(TwoViews(working), 1, 1920, 1080);
  EXPECT_EQ(model.cameras.at(1).width(), 1920);
  EXPECT_EQ(model.cameras.at(1).height(), 1080);
  EXPECT_LT(ReprojectionRms(model), 1e-6);
  const Eigen::Vector3d point = model.points[1].position;
  const Eigen::Vector2d seen = *model.cameras.at(1).Project(model.images[0].cam_from_world * point);
  EXPECT_NEAR((model.images[0].features[1] - seen).norm(), 0, 1e-6);
}

// Two aircraft with different cameras: each image keeps its own, and the model reads back so.
TEST(ColmapModel, ImagesOfTwoCamerasKeepTheirOwn) {
  testing::TempDir dir;
  const Camera first = Camera::Pinhole(640, 480, 450, 451, 319.5, 239.5);
  const Camera second = Camera::Pinhole(752, 480, 458, 457, 367, 248, -0.28, 0.07);
  ColmapModel model = TwoViews(first);
  model.cameras.emplace(2, second);
  model.images[1].camera_id = 2;
  for (size_t p = 0; p < model.points.size(); ++p) {
    model.images[1].features[p] = *second.Project(model.images[1].cam_from_world * model.points[p].position);
  }
  EXPECT_LT(ReprojectionRms(model), 1e-6);
  WriteColmapModel(model, dir / "m");
  const ColmapModel back = ReadColmapModel(dir / "m");
  ASSERT_EQ(back.cameras.size(), 2u);
  EXPECT_EQ(back.cameras.at(2).Describe(), second.Describe());
  EXPECT_EQ(back.images[0].camera_id, 1);
  EXPECT_EQ(back.images[1].camera_id, 2);
  EXPECT_LT(ReprojectionRms(back), 1e-6);
  // Resizing one camera moves only its images' features.
  const ColmapModel resized = ResizeColmapModel(back, 2, 1504, 960);
  EXPECT_EQ(resized.cameras.at(1).width(), 640);
  EXPECT_EQ(resized.cameras.at(2).width(), 1504);
  EXPECT_EQ(resized.images[0].features[0], back.images[0].features[0]);
  EXPECT_LT(ReprojectionRms(resized), 1e-6);
  // An image naming a camera the model does not hold is refused, written or read.
  model.images[1].camera_id = 3;
  EXPECT_THROW(WriteColmapModel(model, dir / "bad"), Error);
  std::ofstream(dir.path() / "m" / "images.txt") << "1 1 0 0 0 0 0 0 7 a.png\n\n";
  try {
    ReadColmapModel(dir / "m");
    ADD_FAILURE() << "an image of camera 7 read";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("names camera 7"), std::string::npos) << e.what();
  }
}

// COLMAP's first pixel centre is (0.5, 0.5): the files say cx + 0.5 and x + 0.5.
TEST(ColmapModel, TheFilesAreInColmapsPixelConvention) {
  testing::TempDir dir;
  WriteColmapModel(TwoViews(Camera::Pinhole(640, 480, 450, 450, 319.5, 239.5)), dir / "m");
  std::ifstream cameras(dir / "m/cameras.txt");
  std::string line, last;
  while (std::getline(cameras, line)) last = line;
  EXPECT_EQ(last, "1 PINHOLE 640 480 450 450 320 240");
  std::ifstream images(dir / "m/images.txt");
  std::vector<std::string> lines;
  while (std::getline(images, line)) lines.push_back(line);
  EXPECT_NE(lines.back().find("10.5 10.5 -1"), std::string::npos) << lines.back();
}

TEST(ColmapModel, MalformedFilesAreClearErrors) {
  testing::TempDir dir;
  const auto error_of = [&](const std::string& file, const std::string& text) {
    WriteColmapModel(TwoViews(Camera::Pinhole(640, 480, 450, 450, 319.5, 239.5)), dir / "m");
    std::ofstream(dir.path() / "m" / file) << text;
    try {
      ReadColmapModel(dir / "m");
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(error_of("cameras.txt", "1 SIMPLE_RADIAL 640 480 450 320 240 0.1\n").find("SIMPLE_RADIAL"),
            std::string::npos);
  EXPECT_NE(error_of("cameras.txt", "1 PINHOLE 640 480 450\n").find("takes 4 parameters"), std::string::npos);
  EXPECT_NE(error_of("images.txt", "1 1 0 0 0 0 0 0 1\n\n").find("IMAGE_ID"), std::string::npos);
  EXPECT_NE(error_of("images.txt", "1 1 0 0 0 0 0 0 1 a.png\n1 2\n").find("triples"), std::string::npos);
  EXPECT_NE(error_of("points3D.txt", "1 0 0 5 1 2 3 0.5 1 0 7 9\n").find("which is not there"), std::string::npos);
  EXPECT_NE(error_of("points3D.txt", "1 0 0 x\n").find("is not a point"), std::string::npos);
  // An image with no features (an empty second line, or none at the end) reads.
  std::ofstream(dir.path() / "m" / "points3D.txt") << "# no points\n";
  std::ofstream(dir.path() / "m" / "images.txt") << "1 1 0 0 0 0 0 0 1 a.png\n\n2 1 0 0 0 0 0 0 1 b.png\n";
  EXPECT_EQ(ReadColmapModel(dir / "m").images.size(), 2u);
  EXPECT_THROW(ReadColmapModel(dir / "nothing"), Error);
}

}  // namespace
}  // namespace stitch
