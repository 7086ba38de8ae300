#include <cmath>
#include <filesystem>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "stitch/mosaic/checkpoints.h"
#include "stitch/mosaic/geotiff.h"
#include "stitch/mosaic/ground_surface.h"
#include "stitch/mosaic/keyframe_imagery.h"
#include "stitch/mosaic/live_mosaic.h"
#include "stitch/mosaic/orthomosaic.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

// A textured flat ground at z = 0 over [-60, 60] m on both axes, 0.05 m per texel: blobs of
// several sizes, so that corners are found at any scale.
class TexturedGround {
 public:
  TexturedGround() : texture_(2400, 2400, CV_8UC1) {
    std::mt19937 random(7);
    cv::Mat noise(texture_.size(), CV_32F);
    cv::randu(noise, 0, 1);
    cv::Mat sum = cv::Mat::zeros(texture_.size(), CV_32F);
    for (const int blur : {3, 9, 31}) {
      cv::Mat blurred;
      cv::GaussianBlur(noise, blurred, cv::Size(0, 0), blur);
      cv::normalize(blurred, blurred, -1, 1, cv::NORM_MINMAX);
      sum += blurred;
    }
    cv::normalize(sum, sum, 20, 235, cv::NORM_MINMAX);
    sum.convertTo(texture_, CV_8U);
  }
  // Ground (x, y) -> texel.
  cv::Point2d Texel(double x, double y) const { return {(x + 60.0) / 0.05 - 0.5, (60.0 - y) / 0.05 - 0.5}; }
  const cv::Mat& texture() const { return texture_; }
  // What a camera sees of it.
  cv::Mat Photograph(const Camera& camera, const Sim3d& cam_from_ground) const {
    const Sim3d ground_from_cam = cam_from_ground.Inverse();
    cv::Mat map_x(camera.height(), camera.width(), CV_32F), map_y(camera.height(), camera.width(), CV_32F);
    for (int r = 0; r < camera.height(); ++r) {
      for (int c = 0; c < camera.width(); ++c) {
        const Eigen::Vector3d ray = ground_from_cam.rotation * camera.PixelToRay(Eigen::Vector2d(c, r));
        const Eigen::Vector3d& centre = ground_from_cam.translation;
        const Eigen::Vector3d hit = centre + ray * (-centre.z() / ray.z());
        const cv::Point2d t = Texel(hit.x(), hit.y());
        map_x.at<float>(r, c) = static_cast<float>(t.x);
        map_y.at<float>(r, c) = static_cast<float>(t.y);
      }
    }
    cv::Mat image;
    cv::remap(texture_, image, map_x, map_y, cv::INTER_LINEAR);
    return image;
  }
  // The truth on the mosaic's grid.
  cv::Mat Orthophoto(const MosaicGrid& grid, int col0, int row0, cv::Size size) const {
    cv::Mat map_x(size, CV_32F), map_y(size, CV_32F);
    for (int r = 0; r < size.height; ++r) {
      for (int c = 0; c < size.width; ++c) {
        const Eigen::Vector2d g = grid.Ground(col0 + c, row0 + r);
        const cv::Point2d t = Texel(g.x(), g.y());
        map_x.at<float>(r, c) = static_cast<float>(t.x);
        map_y.at<float>(r, c) = static_cast<float>(t.y);
      }
    }
    cv::Mat image;
    cv::remap(texture_, image, map_x, map_y, cv::INTER_LINEAR);
    return image;
  }

 private:
  cv::Mat texture_;
};

const TexturedGround& Ground() {
  static const TexturedGround* ground = new TexturedGround();  // built once: a second's work
  return *ground;
}

// A camera `height` m above (x, y), looking down (image x east, y south), tilted by `tilt_deg`
// about its x axis.
Sim3d NadirCamera(double x, double y, double height, double tilt_deg = 0.0) {
  Eigen::Matrix3d cam_from_ground_rotation;
  cam_from_ground_rotation << 1, 0, 0, 0, -1, 0, 0, 0, -1;  // x east, y south, z down
  const Eigen::Matrix3d tilt = Eigen::AngleAxisd(tilt_deg * M_PI / 180.0, Eigen::Vector3d::UnitX()).toRotationMatrix();
  const Eigen::Matrix3d rotation = tilt * cam_from_ground_rotation;
  const Eigen::Vector3d centre(x, y, height);
  return Sim3d(1.0, Eigen::Quaterniond(rotation), -(rotation * centre));
}

const Camera kCamera = Camera::Pinhole(320, 240, 300, 300, 159.5, 119.5);

TEST(GroundSurface, FollowsASlopeAndFillsCellsWithoutPoints) {
  std::vector<Eigen::Vector3d> points;
  for (double x = 0; x <= 40; x += 0.5) {
    for (double y = 0; y <= 40; y += 0.5) {
      if (x > 15 && x < 25 && y > 15 && y < 25) continue;  // a hole in the middle
      points.emplace_back(x, y, 0.1 * x + 0.2 * y);
    }
  }
  const GroundSurface surface = GroundSurface::FromPoints(points, 2.0, 3);
  EXPECT_LT(surface.cells_measured(), surface.cells());
  EXPECT_NEAR(surface.Height(10.3, 31.7), 0.1 * 10.3 + 0.2 * 31.7, 0.05);
  // In the hole, from the neighbours: near the plane, not 0.
  EXPECT_NEAR(surface.Height(20, 20), 6.0, 0.6);
  // Beyond the points: the edge's height.
  EXPECT_NEAR(surface.Height(-100, 10.5), surface.Height(0.5, 10.5), 1e-9);
  EXPECT_NEAR(surface.min_height(), 0.15, 0.1);
  EXPECT_NEAR(surface.max_height(), 11.85, 0.1);
  EXPECT_THROW(GroundSurface::FromPoints({{0, 0, 0}}, 2.0, 3), Error);
  EXPECT_THROW(GroundSurface::FromPoints(points, 0.0, 3), Error);
  // A median per cell: a stray point does not lift it.
  points.emplace_back(5.1, 5.1, 100.0);
  EXPECT_NEAR(GroundSurface::FromPoints(points, 2.0, 3).Height(5, 5), 1.5, 0.1);
}

// A map whose points lie in one corner of a large grid (a stray point far off, a camera that
// looked along the ground): every cell is filled from the corner's heights, ring by ring, each
// cell visited a few times (filling the whole grid once per ring took the merger's live mosaic
// 15-30 s of CPU on a handheld indoor sequence).
TEST(GroundSurface, FillsAGridFarLargerThanItsPointsFromTheirEdge) {
  std::vector<Eigen::Vector3d> points;
  for (double x = 0; x <= 10; x += 0.5) {
    for (double y = 0; y <= 10; y += 0.5) points.emplace_back(x, y, 2.0);
  }
  points.emplace_back(1999.0, 1999.0, -50.0);  // alone in its cell: measures nothing
  const GroundSurface surface = GroundSurface::FromPoints(points, 2.0, 3);
  EXPECT_EQ(surface.cells(), 1000 * 1000);
  EXPECT_GT(surface.cells_measured(), 20);
  EXPECT_LT(surface.cells_measured(), 40);
  EXPECT_NEAR(surface.Height(1998.0, 1998.0), 2.0, 1e-9);
  EXPECT_NEAR(surface.Height(5.0, 1500.0), 2.0, 1e-9);
  EXPECT_NEAR(surface.min_height(), 2.0, 1e-9);
  EXPECT_NEAR(surface.max_height(), 2.0, 1e-9);
}

// A handheld indoor camera's map levelled on its best plane: points strewn 100 km along one axis
// by a few far ones (TUM fr1/rpy's map spread over 194,012 x 314 cells of the live mosaic's
// ground, which stopped the mosaic with an error). The grid spans the bulk of the points; a cell
// grows only as far as that still needs.
TEST(GroundSurface, AMapStrewnFarAlongOneAxisShapesTheGroundOfItsBulk) {
  std::vector<Eigen::Vector3d> points;
  for (double x = 0; x <= 20; x += 0.25) {
    for (double y = 0; y <= 5; y += 0.25) points.emplace_back(x, y, 0.1 * x);
  }
  for (int i = 1; i <= 10; ++i) points.emplace_back(1e4 * i, 2.0, 7.0);  // far ones, under 1%
  const GroundSurface surface = GroundSurface::FromPoints(points, 0.005, 1);
  EXPECT_LE(surface.cells(), 4000000);
  EXPECT_LT(surface.cell(), 0.05);  // the bulk's extent sets it, not the far points'
  EXPECT_NEAR(surface.Height(10.0, 2.0), 1.0, 0.05);
  EXPECT_NEAR(surface.max_height(), 2.0, 0.05);  // the far points shape no cell
  // Spread beyond any trimming: the cell grows.
  std::vector<Eigen::Vector3d> spread;
  for (double x = 0; x <= 1e5; x += 100) spread.emplace_back(x, 0.5 * (static_cast<int>(x) % 3), 1.0);
  const GroundSurface coarse = GroundSurface::FromPoints(spread, 0.001, 1);
  EXPECT_LE(coarse.cells(), 4000000);
  EXPECT_GT(coarse.cell(), 0.001);
  EXPECT_NEAR(coarse.Height(5e4, 0.5), 1.0, 1e-9);
}

TEST(Orthomosaic, NadirImagesOfTexturedGroundGiveItsOrthophoto) {
  const TexturedGround& ground = Ground();
  MosaicOptions options;
  options.tile_px = 64;
  MosaicGrid grid;
  grid.gsd = 0.1;
  Orthomosaic mosaic(options, grid, GroundSurface(0.0));
  int id = 0;
  // A 2 x 2 block of images, slightly tilted, in a map of another scale.
  for (const double x : {-8.0, 8.0}) {
    for (const double y : {-6.0, 6.0}) {
      const Sim3d pose = NadirCamera(x, y, 30.0, x > 0 ? 3.0 : -2.0);
      EXPECT_NEAR(*NadirGsd(kCamera, pose, mosaic.surface()), 0.1, 1e-9);
      const Orthomosaic::Change change = mosaic.SetImage(id++, kCamera, pose, ground.Photograph(kCamera, pose));
      EXPECT_GT(change.pixels, 0);
    }
  }
  const MosaicRaster raster = mosaic.Render();
  ASSERT_FALSE(raster.colour.empty());
  // Four 32 x 24 m footprints overlapping by 16 x 12 m: about 48 x 36 m at 0.1 m.
  EXPECT_NEAR(cv::countNonZero(raster.coverage), 480 * 360, 0.06 * 480 * 360);
  EXPECT_EQ(mosaic.covered_pixels(), cv::countNonZero(raster.coverage));
  const cv::Mat truth = ground.Orthophoto(grid, raster.col0, raster.row0, raster.colour.size());
  const CheckpointErrors errors = MeasureCheckpoints(truth, raster.colour, raster.coverage);
  EXPECT_GT(errors.checkpoints, 100);
  EXPECT_LT(errors.rms_px, 0.3);
  // Grey in, the same grey in every channel out.
  cv::Mat planes[3];
  cv::split(raster.colour, planes);
  EXPECT_EQ(cv::countNonZero(planes[0] != planes[2]), 0);
}

TEST(Orthomosaic, EachPixelComesFromTheImageNearestItsNadir) {
  MosaicOptions options;
  options.tile_px = 32;
  MosaicGrid grid;
  grid.gsd = 0.2;
  Orthomosaic mosaic(options, grid, GroundSurface(0.0));
  const cv::Mat dark(240, 320, CV_8UC1, cv::Scalar(50)), bright(240, 320, CV_8UC1, cv::Scalar(200));
  mosaic.SetImage(1, kCamera, NadirCamera(0, 0, 30), dark);
  mosaic.SetImage(2, kCamera, NadirCamera(10, 0, 30), bright);
  const MosaicRaster raster = mosaic.Render();
  const auto value_at = [&](double x, double y) {
    const Eigen::Vector2d p = grid.Pixel({x, y});
    return raster.colour.at<cv::Vec3b>(static_cast<int>(std::lround(p.y())) - raster.row0,
                                       static_cast<int>(std::lround(p.x())) - raster.col0)[0];
  };
  EXPECT_EQ(value_at(1, 3), 50);
  EXPECT_EQ(value_at(4.7, -3), 50);
  EXPECT_EQ(value_at(5.3, 2), 200);
  EXPECT_EQ(value_at(9, 1), 200);
  // What only one sees comes from it.
  EXPECT_EQ(value_at(-12, 0), 50);
  EXPECT_EQ(value_at(22, 0), 200);
  // Two images seeing a pixel alike: the lower id gives it, whichever came first.
  const cv::Mat mid(240, 320, CV_8UC1, cv::Scalar(120));
  mosaic.SetImage(3, kCamera, NadirCamera(0, 0, 30), mid);
  EXPECT_EQ(mosaic.Render().colour.at<cv::Vec3b>(raster.coverage.rows / 2, 10)[0], 50);
  mosaic.SetImage(0, kCamera, NadirCamera(0, 0, 30), mid);
  EXPECT_EQ(mosaic.Render().colour.at<cv::Vec3b>(raster.coverage.rows / 2, 10)[0], 120);
}

TEST(Orthomosaic, AnImageMovedOrRemovedRedrawsItsTilesAsIfAddedThereOrNever) {
  const TexturedGround& ground = Ground();
  MosaicOptions options;
  options.tile_px = 48;
  MosaicGrid grid;
  grid.gsd = 0.1;
  const auto build = [&](const std::vector<std::pair<int, Sim3d>>& poses) {
    Orthomosaic mosaic(options, grid, GroundSurface(0.0));
    for (const auto& [id, pose] : poses) mosaic.SetImage(id, kCamera, pose, ground.Photograph(kCamera, pose));
    return mosaic;
  };
  const Sim3d a = NadirCamera(0, 0, 30), b = NadirCamera(12, 3, 30), c = NadirCamera(-5, 10, 28, 4);
  // Image 2 drawn at a wrong pose, then moved where it belongs, keeping its pixels.
  const Sim3d c_wrong = NadirCamera(-9, 14, 28, 4);
  Orthomosaic moved(options, grid, GroundSurface(0.0));
  moved.SetImage(0, kCamera, a, ground.Photograph(kCamera, a));
  moved.SetImage(1, kCamera, b, ground.Photograph(kCamera, b));
  moved.SetImage(2, kCamera, c_wrong, ground.Photograph(kCamera, c));
  Orthomosaic::Change change;
  ASSERT_TRUE(moved.MoveImage(2, c, &change));
  EXPECT_GT(change.tiles, 0);
  const Orthomosaic fresh = build({{0, a}, {1, b}, {2, c}});
  const MosaicRaster m = moved.Render(), f = fresh.Render();
  ASSERT_EQ(m.colour.size(), f.colour.size());
  EXPECT_EQ(m.col0, f.col0);
  EXPECT_EQ(m.row0, f.row0);
  EXPECT_EQ(cv::norm(m.colour, f.colour, cv::NORM_INF), 0);
  EXPECT_EQ(cv::norm(m.coverage, f.coverage, cv::NORM_INF), 0);
  // Several moved at once (a map refined as a whole), their tiles drawn again once: the same.
  Orthomosaic together(options, grid, GroundSurface(0.0));
  together.SetImage(0, kCamera, c_wrong, ground.Photograph(kCamera, a));
  together.SetImage(1, kCamera, b, ground.Photograph(kCamera, b));
  together.SetImage(2, kCamera, a, ground.Photograph(kCamera, c));
  EXPECT_EQ(together.MoveImages({{0, a}, {2, c}, {7, b}}), 2);  // 7 is not there
  const MosaicRaster t = together.Render();
  ASSERT_EQ(t.colour.size(), f.colour.size());
  EXPECT_EQ(cv::norm(t.colour, f.colour, cv::NORM_INF), 0);
  EXPECT_EQ(cv::norm(t.coverage, f.coverage, cv::NORM_INF), 0);
  // Removed: as if never added.
  ASSERT_TRUE(moved.RemoveImage(1));
  EXPECT_FALSE(moved.RemoveImage(1));
  EXPECT_FALSE(moved.MoveImage(7, a));
  const MosaicRaster without = moved.Render(), never = build({{0, a}, {2, c}}).Render();
  ASSERT_EQ(without.colour.size(), never.colour.size());
  EXPECT_EQ(cv::norm(without.colour, never.colour, cv::NORM_INF), 0);
  // An image not looking at the ground (the camera under it) adds nothing; a bad image is refused.
  Orthomosaic empty(options, grid, GroundSurface(50.0));
  EXPECT_EQ(empty.SetImage(0, kCamera, a, ground.Photograph(kCamera, a)).pixels, 0);
  EXPECT_TRUE(empty.Render().colour.empty());
  EXPECT_THROW(empty.SetImage(1, kCamera, a, cv::Mat(10, 10, CV_32F)), Error);
  MosaicOptions bad;
  bad.max_off_nadir_deg = 95;
  EXPECT_THROW(Orthomosaic(bad, grid, GroundSurface(0.0)), Error);
}

TEST(Orthomosaic, APoseInAScaledMapFrameGivesTheSameMosaic) {
  // Only directions matter to where a pixel falls: the map's scale does not move the mosaic.
  const TexturedGround& ground = Ground();
  MosaicOptions options;
  MosaicGrid grid;
  grid.gsd = 0.1;
  const Sim3d pose = NadirCamera(2, 1, 30, 5);
  const cv::Mat image = ground.Photograph(kCamera, pose);
  Orthomosaic metric(options, grid, GroundSurface(0.0));
  metric.SetImage(0, kCamera, pose, image);
  // The camera's frame in map units: cam_from_ground scaled; the ground in the same frame.
  Orthomosaic scaled(options, grid, GroundSurface(0.0));
  scaled.SetImage(0, kCamera, Sim3d(0.37, Eigen::Quaterniond::Identity(), Eigen::Vector3d::Zero()) * pose, image);
  EXPECT_EQ(cv::norm(metric.Render().colour, scaled.Render().colour, cv::NORM_INF), 0);
}

TEST(Checkpoints, MeasureAKnownShiftAndTakeItOutWithASimilarity) {
  const TexturedGround& ground = Ground();
  MosaicGrid grid;
  grid.gsd = 0.1;
  const cv::Mat truth = ground.Orthophoto(grid, -200, -200, cv::Size(400, 400));
  // The mosaic 3 px east and 2 px north of the truth: its content shifted right and up.
  const cv::Mat shifted = ground.Orthophoto(grid, -203, -198, cv::Size(400, 400));
  const cv::Mat all(400, 400, CV_8UC1, cv::Scalar(255));
  const CheckpointErrors same = MeasureCheckpoints(truth, truth, all);
  EXPECT_GT(same.checkpoints, 50);
  EXPECT_LT(same.rms_px, 0.05);
  const CheckpointErrors errors = MeasureCheckpoints(truth, shifted, all);
  EXPECT_GT(errors.checkpoints, 50);
  EXPECT_NEAR(errors.rms_px, std::hypot(3, 2), 0.15);
  EXPECT_NEAR(errors.mean_offset_px.x(), 3, 0.15);
  EXPECT_NEAR(errors.mean_offset_px.y(), -2, 0.15);
  EXPECT_LT(errors.rms_after_similarity_px, 0.15);
  EXPECT_NEAR(errors.similarity_scale, 1.0, 0.002);
  // Where nothing is drawn there is nothing to measure.
  EXPECT_EQ(MeasureCheckpoints(truth, shifted, cv::Mat::zeros(400, 400, CV_8UC1)).checkpoints, 0);
  EXPECT_THROW(MeasureCheckpoints(truth, shifted(cv::Rect(0, 0, 10, 10)), all), Error);
}

TEST(Checkpoints, ASimilarityIsFittedExactlyWhereThereIsOne) {
  // UTM-sized coordinates, turned by 1.2 degrees and scaled by the projection's 0.9996.
  const double angle = 1.2 * M_PI / 180.0, scale = 0.9996;
  std::vector<Eigen::Vector2d> from, to;
  for (int i = 0; i < 5; ++i) {
    for (int j = 0; j < 5; ++j) {
      const Eigen::Vector2d p(-300 + 150 * i, -200 + 100 * j);
      from.push_back(p);
      to.push_back(scale * Eigen::Rotation2Dd(angle).toRotationMatrix() * p + Eigen::Vector2d(649'312.5, 5'318'044.25));
    }
  }
  const Similarity2d fit = FitSimilarity2d(from, to);
  EXPECT_NEAR(fit.scale(), scale, 1e-12);
  EXPECT_NEAR(fit.angle(), angle, 1e-12);
  for (size_t i = 0; i < from.size(); ++i) EXPECT_LT((fit * from[i] - to[i]).norm(), 1e-6);
  EXPECT_THROW(FitSimilarity2d({from[0]}, {to[0]}), Error);
  EXPECT_THROW(FitSimilarity2d({from[0], from[0]}, {to[0], to[1]}), Error);
}

TEST(GeoTiff, WritesWhatItReadsBackWithItsCrsAndOverviews) {
  testing::TempDir dir;
  GeoTiffImage image;
  image.colour = cv::Mat(700, 900, CV_8UC3);
  cv::randu(image.colour, 0, 255);
  image.coverage = cv::Mat(700, 900, CV_8UC1, cv::Scalar(255));
  image.coverage(cv::Rect(0, 0, 100, 100)).setTo(0);
  image.west = 648'000.25;
  image.north = 5'318'000.75;
  image.pixel_size = 0.15;
  image.epsg = 32632;
  image.metadata["STITCH_GSD_M"] = "0.15";
  const std::string path = dir / "ortho.tif";
  WriteGeoTiff(path, image);
  EXPECT_FALSE(std::filesystem::exists(path + ".partial"));
  const GeoTiffInfo info = ReadGeoTiffInfo(path);
  EXPECT_EQ(info.width, 900);
  EXPECT_EQ(info.height, 700);
  EXPECT_EQ(info.bands, 4);
  EXPECT_EQ(info.epsg, 32632);
  EXPECT_DOUBLE_EQ(info.geo_transform[0], 648'000.25);
  EXPECT_DOUBLE_EQ(info.geo_transform[1], 0.15);
  EXPECT_DOUBLE_EQ(info.geo_transform[3], 5'318'000.75);
  EXPECT_DOUBLE_EQ(info.geo_transform[5], -0.15);
  EXPECT_GE(info.overviews, 1);
  EXPECT_EQ(info.metadata.at("STITCH_GSD_M"), "0.15");
  const GeoTiffImage back = ReadGeoTiff(path);
  EXPECT_EQ(cv::norm(back.colour, image.colour, cv::NORM_INF), 0);
  EXPECT_EQ(cv::norm(back.coverage, image.coverage, cv::NORM_INF), 0);
  // A local frame: no CRS.
  image.epsg = 0;
  WriteGeoTiff(dir / "local.tif", image);
  EXPECT_EQ(ReadGeoTiffInfo(dir / "local.tif").epsg, 0);
  EXPECT_EQ(ReadGeoTiffInfo(dir / "local.tif").crs, "");
  // A CRS in PROJ's words: the live mosaic's, east and north of the first fix.
  image.crs = "+proj=ortho +lat_0=48.1 +lon_0=11.2 +ellps=WGS84 +units=m +no_defs";
  WriteGeoTiff(dir / "ortho_projection.tif", image);
  const std::string crs = ReadGeoTiffInfo(dir / "ortho_projection.tif").crs;
  EXPECT_NE(crs.find("+proj=ortho"), std::string::npos) << crs;
  EXPECT_NE(crs.find("+lat_0=48.1 "), std::string::npos) << crs;
  EXPECT_NE(crs.find("+lon_0=11.2 "), std::string::npos) << crs;
  image.crs = "+proj=nothing";
  EXPECT_THROW(WriteGeoTiff(dir / "bad_crs.tif", image), Error);
  image.crs.clear();
  // Refusals name the file and leave nothing behind.
  EXPECT_THROW(WriteGeoTiff(dir / "missing/ortho.tif", image), Error);
  image.epsg = 1;
  EXPECT_THROW(WriteGeoTiff(dir / "bad.tif", image), Error);
  EXPECT_FALSE(std::filesystem::exists(dir / "bad.tif"));
  EXPECT_FALSE(std::filesystem::exists(dir / "bad.tif.partial"));
  EXPECT_THROW(ReadGeoTiffInfo(dir / "nothing.tif"), Error);
}

// A map whose points stand far off their plane against the cameras' height (a room seen by a
// handheld camera, TUM fr1/rpy: 0.34-8.5 of the height in the merger's log) is not a ground seen
// from above: no live mosaic, and the reason said. With a looser limit the same map is drawn.
TEST(LiveMosaic, AMapThatIsNotAGroundSeenFromAboveGetsNoMosaicAndSaysWhy) {
  const TexturedGround& ground = Ground();
  LiveMosaic::MapState state;
  state.frame = 1;
  int i = 0;
  for (double x = -30; x <= 30; x += 1.5) {
    for (double y = -25; y <= 25; y += 1.5) state.points.emplace_back(x, y, 12.0 * (i++ % 3 - 1));
  }
  const Sim3d pose = NadirCamera(0, 0, 30);
  const Sim3d world_from_cam = pose.Inverse();
  state.world_from_cam[0] = Rigid3d(world_from_cam.rotation, world_from_cam.translation);
  std::vector<uint8_t> jpeg;
  cv::imencode(".jpg", ground.Photograph(kCamera, pose), jpeg);
  MosaicOptions options;
  options.live_min_pictures = 1;
  LiveMosaic refused(options);
  refused.AddPicture(0, kCamera, jpeg);
  EXPECT_EQ(refused.Update(state).laid, 0);  // relief 9.8 against a height of 30: 0.33
  EXPECT_EQ(refused.mosaic(), nullptr);
  EXPECT_NE(refused.waiting_for().find("a ground seen from above"), std::string::npos) << refused.waiting_for();
  options.live_max_relief = 0.4;
  LiveMosaic drawn(options);
  drawn.AddPicture(0, kCamera, jpeg);
  EXPECT_EQ(drawn.Update(state).laid, 1);
  EXPECT_NE(drawn.mosaic(), nullptr);
  EXPECT_EQ(drawn.waiting_for(), "");
}

// A map's relief against its cameras' height: a field seen from 30 m, 0; the same points 12 m
// above and below it, about a third, from either side of it.
TEST(ReliefOverHeight, TellsAGroundSeenFromAboveFromARoom) {
  std::vector<Eigen::Vector3d> field, room;
  int i = 0;
  for (double x = -30; x <= 30; x += 1.5) {
    for (double y = -25; y <= 25; y += 1.5) {
      field.emplace_back(x, y, 0.0);
      room.emplace_back(x, y, 12.0 * (i++ % 3 - 1));
    }
  }
  const std::vector<Eigen::Vector3d> cameras = {{-8, -4, 30}, {8, -4, 30}, {0, 8, 30}};
  EXPECT_NEAR(ReliefOverHeight(field, cameras), 0.0, 1e-9);
  EXPECT_NEAR(ReliefOverHeight(room, cameras), std::sqrt(2.0 / 3.0) * 12.0 / 30.0, 0.02);
  // The plane's side is the cameras': a height of 30 whichever way the map's z points.
  EXPECT_NEAR(ReliefOverHeight(room, {{0, 0, -30}}), std::sqrt(2.0 / 3.0) * 12.0 / 30.0, 0.02);
  EXPECT_THROW(ReliefOverHeight(field, {}), Error);
}

// A map's relief is judged once it places live_min_pictures pictures (a few cameras close
// together see a young room as flat), and a mosaic drawn on a map that later turns out not to be
// a ground seen from above is withdrawn: its tiles cleared for a viewer, nothing left to write.
TEST(LiveMosaic, WaitsForEnoughPicturesAndWithdrawsAMosaicWhoseGroundTurnsOutNotToBeOne) {
  const TexturedGround& ground = Ground();
  LiveMosaic::MapState state;
  state.frame = 1;
  for (double x = -30; x <= 30; x += 1.5) {
    for (double y = -25; y <= 25; y += 1.5) state.points.emplace_back(x, y, 0.0);
  }
  MosaicOptions options;
  options.tile_px = 64;
  options.live_min_pictures = 3;
  LiveMosaic live(options);
  const std::vector<Sim3d> poses = {NadirCamera(-8, -4, 30), NadirCamera(8, -4, 30), NadirCamera(0, 8, 30)};
  for (int k = 0; k < 3; ++k) {
    std::vector<uint8_t> jpeg;
    cv::imencode(".jpg", ground.Photograph(kCamera, poses[k]), jpeg);
    live.AddPicture(k, kCamera, std::move(jpeg));
    const Sim3d world_from_cam = poses[k].Inverse();
    if (k < 2) state.world_from_cam[k] = Rigid3d(world_from_cam.rotation, world_from_cam.translation);
  }
  EXPECT_EQ(live.Update(state).laid, 0);  // two of three pictures placed
  EXPECT_EQ(live.mosaic(), nullptr);
  EXPECT_NE(live.waiting_for().find("placing 3 pictures"), std::string::npos) << live.waiting_for();
  const Sim3d third = poses[2].Inverse();
  state.world_from_cam[2] = Rigid3d(third.rotation, third.translation);
  EXPECT_EQ(live.Update(state).laid, 3);
  ASSERT_NE(live.mosaic(), nullptr);
  EXPECT_FALSE(live.TakeChangedTiles().empty());
  const int64_t drawn_revision = live.revision();
  // The map grows into a room: its points double, now 12 units above and below the plane.
  const size_t flat = state.points.size();
  for (size_t i = 0; i < flat; ++i) {
    state.points.push_back(state.points[i] + Eigen::Vector3d(0.5, 0.5, i % 2 ? 12.0 : -12.0));
  }
  const LiveMosaic::Change change = live.Update(state);
  EXPECT_TRUE(change.withdrawn);
  EXPECT_EQ(change.laid, 0);
  EXPECT_EQ(live.mosaic(), nullptr);
  EXPECT_NE(live.waiting_for().find("a ground seen from above"), std::string::npos) << live.waiting_for();
  EXPECT_GT(live.revision(), drawn_revision);
  const std::vector<LiveMosaicTile> cleared = live.TakeChangedTiles();
  ASSERT_EQ(cleared.size(), 1u);  // one empty tile of the new revision: a viewer drops the old ones
  EXPECT_EQ(cleared[0].revision, live.revision());
  EXPECT_TRUE(cleared[0].png.empty());
  EXPECT_GT(cleared[0].grid.gsd, 0);
  EXPECT_TRUE(live.TakeChangedTiles().empty());
  EXPECT_FALSE(live.Update(state).withdrawn);  // said once
}

// The live mosaic on a map that is not metric and not level (a SLAM map's frame): pictures laid
// once, moved when the map moves them, all drawn again when the map's frame changes, taken out
// when the map no longer places them.
// The mosaic's pixels against the textured ground's where `true_from_mosaic` puts them.
CheckpointErrors AgainstTheTrueGround(const Orthomosaic& mosaic, const Sim3d& true_from_mosaic) {
  const MosaicRaster raster = mosaic.Render();
  cv::Mat map_x(raster.colour.size(), CV_32F), map_y(raster.colour.size(), CV_32F);
  for (int r = 0; r < raster.colour.rows; ++r) {
    for (int c = 0; c < raster.colour.cols; ++c) {
      const Eigen::Vector2d g = mosaic.grid().Ground(raster.col0 + c, raster.row0 + r);
      const Eigen::Vector3d p = true_from_mosaic * Eigen::Vector3d(g.x(), g.y(), mosaic.surface().Height(g.x(), g.y()));
      const cv::Point2d t = Ground().Texel(p.x(), p.y());
      map_x.at<float>(r, c) = static_cast<float>(t.x);
      map_y.at<float>(r, c) = static_cast<float>(t.y);
    }
  }
  cv::Mat truth;
  cv::remap(Ground().texture(), truth, map_x, map_y, cv::INTER_LINEAR);
  return MeasureCheckpoints(truth, raster.colour, raster.coverage);
}

TEST(LiveMosaic, LaysPicturesWhereTheMapPlacesThemAndFollowsTheMap) {
  const TexturedGround& ground = Ground();
  // map = s R ground + t: any similarity.
  const Sim3d map_from_ground(0.05, Eigen::Quaterniond(Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized())),
                              Eigen::Vector3d(1, -2, 0.5));
  LiveMosaic::MapState state;
  state.frame = 1;
  for (double x = -30; x <= 30; x += 1.5) {
    for (double y = -25; y <= 25; y += 1.5) state.points.push_back(map_from_ground * Eigen::Vector3d(x, y, 0));
  }
  const auto in_map = [&](const Sim3d& cam_from_ground) {
    const Sim3d ground_from_cam = cam_from_ground.Inverse();
    return Rigid3d((map_from_ground.rotation * ground_from_cam.rotation).normalized(),
                   map_from_ground * ground_from_cam.translation);
  };
  MosaicOptions options;
  options.tile_px = 64;
  options.live_min_pictures = 1;
  LiveMosaic live(options);
  const std::vector<Sim3d> poses = {NadirCamera(-8, -4, 30), NadirCamera(8, -4, 30, 2), NadirCamera(0, 8, 30)};
  for (int k = 0; k < 3; ++k) {
    std::vector<uint8_t> jpeg;
    cv::imencode(".jpg", ground.Photograph(kCamera, poses[k]), jpeg, {cv::IMWRITE_JPEG_QUALITY, 95});
    live.AddPicture(k, kCamera, std::move(jpeg));
  }
  // Too few points to shape the ground yet: nothing.
  LiveMosaic::MapState young = state;
  young.points.resize(10);
  young.world_from_cam[0] = in_map(poses[0]);
  EXPECT_EQ(live.Update(young).laid, 0);
  EXPECT_EQ(live.mosaic(), nullptr);
  for (int k = 0; k < 3; ++k) state.world_from_cam[k] = in_map(poses[k]);
  LiveMosaic::Change change = live.Update(state);
  EXPECT_EQ(change.laid, 3);
  EXPECT_TRUE(change.redrawn);
  ASSERT_NE(live.mosaic(), nullptr);
  // The images' own resolution, 0.1 m, in map units.
  EXPECT_NEAR(live.mosaic()->grid().gsd, 0.1 * 0.05, 1e-6);
  // Against the truth: each mosaic pixel's place on the true ground, through the mosaic's frame.
  {
    const CheckpointErrors errors =
        AgainstTheTrueGround(*live.mosaic(), map_from_ground.Inverse() * live.ground_from_map().Inverse());
    EXPECT_GT(errors.checkpoints, 50);
    EXPECT_LT(errors.rms_px, 0.5);
  }
  // The tiles for a viewer: every tile drawn, each a PNG of its side with the mosaic's pixels and
  // its coverage as alpha; then only what changes.
  const std::vector<LiveMosaicTile> first = live.TakeChangedTiles();
  EXPECT_EQ(first.size(), live.mosaic()->TileKeys().size());
  for (const LiveMosaicTile& tile : first) {
    EXPECT_EQ(tile.revision, live.revision());
    const cv::Mat png = cv::imdecode(tile.png, cv::IMREAD_UNCHANGED);
    ASSERT_EQ(png.type(), CV_8UC4);
    EXPECT_EQ(png.rows, options.tile_px);
    const MosaicRaster raster = live.mosaic()->Tile(tile.col, tile.row);
    std::vector<cv::Mat> channels;
    cv::split(png, channels);
    EXPECT_EQ(cv::countNonZero(channels[3] != raster.coverage), 0);
    cv::Mat colour;
    cv::merge(std::vector<cv::Mat>(channels.begin(), channels.begin() + 3), colour);
    EXPECT_EQ(cv::norm(colour, raster.colour, cv::NORM_INF), 0.0);
  }
  // Nothing moved: nothing to do.
  change = live.Update(state);
  EXPECT_EQ(change.laid + change.moved, 0);
  EXPECT_FALSE(change.redrawn);
  EXPECT_TRUE(live.TakeChangedTiles().empty());
  // The map moved picture 1 (an adjustment): it is moved, its tiles redrawn and sent again.
  state.world_from_cam[1] = in_map(NadirCamera(8.5, -4, 30, 2));
  change = live.Update(state);
  EXPECT_EQ(change.moved, 1);
  EXPECT_GT(change.tiles, 0);
  const std::vector<LiveMosaicTile> moved = live.TakeChangedTiles();
  EXPECT_EQ(static_cast<int>(moved.size()), change.tiles);
  for (const LiveMosaicTile& tile : moved) EXPECT_GT(tile.version, first.back().version);
  // A sliver of movement (under half a mosaic pixel) is not a move.
  state.world_from_cam[1] = in_map(NadirCamera(8.52, -4, 30, 2));
  EXPECT_EQ(live.Update(state).moved, 0);
  // Picture 2's frame left the map: taken out.
  state.world_from_cam.erase(2);
  const int64_t before = live.mosaic()->covered_pixels();
  live.Update(state);
  EXPECT_LT(live.mosaic()->covered_pixels(), before);
  EXPECT_EQ(live.laid(), 2);
  // The map's frame changed (a merge into a larger map): all drawn again, a new revision.
  const int64_t revision = live.revision();
  live.TakeChangedTiles();
  state.frame = 2;
  change = live.Update(state);
  EXPECT_TRUE(change.redrawn);
  EXPECT_EQ(change.laid, 2);
  EXPECT_EQ(live.revision(), revision + 1);
  EXPECT_EQ(live.TakeChangedTiles().size(), live.mosaic()->TileKeys().size());
}

// Maps the GNSS fixes place come in their ENU frame (metres: east, north, up): that is the
// mosaic's frame, north up, not one levelled on their points along their widest spread.
TEST(LiveMosaic, MapsOnEarthAreDrawnInTheFixesFrameNorthUp) {
  // The textured ground turned 30 degrees from north, 20 m east and 100 m up of the first fix.
  const Sim3d enu_from_ground(1.0, Eigen::Quaterniond(Eigen::AngleAxisd(0.52, Eigen::Vector3d::UnitZ())),
                              Eigen::Vector3d(20, 0, 100));
  LiveMosaic::MapState state;
  state.frame = LiveMosaic::kFrameOnEarth;
  state.on_earth = true;
  for (double x = -30; x <= 30; x += 1.5) {
    for (double y = -12; y <= 12; y += 1.5) state.points.push_back(enu_from_ground * Eigen::Vector3d(x, y, 0));
  }
  MosaicOptions options;
  options.tile_px = 64;
  options.live_min_pictures = 1;
  LiveMosaic live(options);
  const std::vector<Sim3d> poses = {NadirCamera(-8, -2, 30), NadirCamera(8, 2, 30, 2)};
  for (int k = 0; k < 2; ++k) {
    std::vector<uint8_t> jpeg;
    cv::imencode(".jpg", Ground().Photograph(kCamera, poses[k]), jpeg, {cv::IMWRITE_JPEG_QUALITY, 95});
    live.AddPicture(k, kCamera, std::move(jpeg));
    const Sim3d ground_from_cam = poses[k].Inverse();
    state.world_from_cam[k] = Rigid3d((enu_from_ground.rotation * ground_from_cam.rotation).normalized(),
                                      enu_from_ground * ground_from_cam.translation);
  }
  EXPECT_EQ(live.Update(state).laid, 2);
  ASSERT_NE(live.mosaic(), nullptr);
  EXPECT_EQ(live.frame(), LiveMosaic::kFrameOnEarth);
  EXPECT_NEAR(live.mosaic()->grid().gsd, 0.1, 1e-6);  // metres
  EXPECT_TRUE(live.ground_from_map().rotation.isApprox(Eigen::Quaterniond::Identity()));
  EXPECT_EQ(live.ground_from_map().translation, Eigen::Vector3d::Zero());
  // Each pixel where ENU puts it: against the truth through the fixes' frame alone.
  const CheckpointErrors errors = AgainstTheTrueGround(*live.mosaic(), enu_from_ground.Inverse());
  EXPECT_GT(errors.checkpoints, 30);
  EXPECT_LT(errors.rms_px, 0.5);
}

TEST(KeyframeImagePicker, SendsASubmapsFirstKeyframeThenWhereTheViewMovedOn) {
  KeyframeImageOptions options;
  options.min_view_change = 0.25;
  KeyframeImagePicker picker(options);
  // 320 x 240 at 300 px: the footprint at unit depth is 0.8 across its narrower side.
  const auto at = [](double x, double yaw_deg = 0.0) {
    return Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(yaw_deg * M_PI / 180.0, Eigen::Vector3d::UnitZ())),
                   Eigen::Vector3d(x, 0, 0));
  };
  EXPECT_TRUE(picker.Take(1, at(0), kCamera));
  EXPECT_FALSE(picker.Take(1, at(0.1), kCamera));
  EXPECT_FALSE(picker.Take(1, at(0.19), kCamera));
  EXPECT_TRUE(picker.Take(1, at(0.21), kCamera));  // a quarter of 0.8 from the last one sent
  EXPECT_FALSE(picker.Take(1, at(0.3), kCamera));
  // Turned by a quarter of the 43.6-degree field of view.
  EXPECT_TRUE(picker.Take(1, at(0.21, 11.5), kCamera));
  // A new submap's first keyframe, wherever it is.
  EXPECT_TRUE(picker.Take(2, at(0.21, 11.5), kCamera));
  options.send = false;
  EXPECT_FALSE(KeyframeImagePicker(options).Take(1, at(0), kCamera));
  // The picture: reduced to max_side_px, a JPEG of that size.
  options.max_side_px = 160;
  cv::Size size;
  const std::vector<uint8_t> jpeg =
      EncodeKeyframePicture(Ground().Photograph(kCamera, NadirCamera(0, 0, 30)), options, &size);
  EXPECT_EQ(size, cv::Size(160, 120));
  const cv::Mat decoded = cv::imdecode(jpeg, cv::IMREAD_UNCHANGED);
  EXPECT_EQ(decoded.size(), size);
  EXPECT_EQ(decoded.channels(), 1);
  EXPECT_THROW(EncodeKeyframePicture(cv::Mat(), options, &size), Error);
  std::string why;
  options.jpeg_quality = 0;
  EXPECT_FALSE(options.Check(&why));
}

}  // namespace
}  // namespace stitch
