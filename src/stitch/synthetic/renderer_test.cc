#include "stitch/synthetic/renderer.h"

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "stitch/synthetic/synthetic_sequence.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

SyntheticOptions SmallFlight() {
  SyntheticOptions options;
  options.flight.num_frames = 60;
  options.flight.num_strips = 2;
  options.flight.strip_length_m = 80;
  options.world.num_buildings = 12;
  return options;
}

constexpr double kMarkerRadiusM = 0.6;

// Intensity-weighted centroid of the bright marker disc around `guess`, over a circle that stays
// inside the marker's black ring (so the texture around it does not pull the centroid).
Eigen::Vector2d MarkerCentroid(const cv::Mat& image, const Eigen::Vector2d& guess, double depth_m, double focal_px) {
  const double radius = 1.5 * kMarkerRadiusM * focal_px / depth_m;
  double sum = 0, sx = 0, sy = 0;
  for (int y = static_cast<int>(guess.y() - radius); y <= static_cast<int>(guess.y() + radius) + 1; ++y) {
    for (int x = static_cast<int>(guess.x() - radius); x <= static_cast<int>(guess.x() + radius) + 1; ++x) {
      if (x < 0 || y < 0 || x >= image.cols || y >= image.rows) continue;
      if ((Eigen::Vector2d(x, y) - guess).norm() > radius) continue;
      const double w = std::max(0.0, image.at<uint8_t>(y, x) - 20.0);
      sum += w;
      sx += w * x;
      sy += w * y;
    }
  }
  return {sx / sum, sy / sum};
}

TEST(Renderer, MarkersLandWhereTheCameraModelProjectsThem) {
  SyntheticOptions options = SmallFlight();
  options.world.num_buildings = 0;  // nothing may hide a marker
  SyntheticSequence sequence(options, FailureSchedule());
  SyntheticWorld& world = sequence.mutable_world();
  const Camera& camera = sequence.camera();
  Rng rng(5);
  for (int frame : {0, 17, 40}) {
    // A view tilted by the wind, and markers spread over the image.
    const Rigid3d world_from_cam = sequence.flight().WorldFromCam(frame);
    std::vector<std::pair<Eigen::Vector3d, Eigen::Vector2d>> markers;
    for (int m = 0; m < 6; ++m) {
      const Eigen::Vector2d target(rng.Uniform(60, camera.width() - 60), rng.Uniform(60, camera.height() - 60));
      // Intersect the pixel's ray with the terrain (fixed-point iteration on the height).
      const Eigen::Vector3d ray = world_from_cam.rotation * camera.PixelToRay(target);
      Eigen::Vector3d point = world_from_cam.translation;
      double z = 0;
      for (int it = 0; it < 50; ++it) {
        point = world_from_cam.translation + ray * ((z - world_from_cam.translation.z()) / ray.z());
        z = world.TerrainHeight(point.x(), point.y());
      }
      point.z() = world.TerrainHeight(point.x(), point.y());
      world.PaintMarker(point.x(), point.y(), kMarkerRadiusM);
      markers.push_back({point, *camera.Project(world_from_cam.Inverse() * point)});
    }
    const cv::Mat image = Renderer(world, camera).Render(world_from_cam.Inverse());
    for (const auto& [point, projected] : markers) {
      const double depth = (world_from_cam.Inverse() * point).z();
      const Eigen::Vector2d centroid = MarkerCentroid(image, projected, depth, camera.fx());
      EXPECT_LT((centroid - projected).norm(), 0.5)
          << "frame " << frame << " marker at " << projected.transpose() << " rendered at " << centroid.transpose();
    }
  }
}

TEST(Renderer, TheTrueOrthophotoHasEveryMarkerWhereItLies) {
  SyntheticOptions options = SmallFlight();
  options.world.num_buildings = 0;
  SyntheticSequence sequence(options, FailureSchedule());
  SyntheticWorld& world = sequence.mutable_world();
  // North up at 0.1 m a pixel around the flight's first camera, markers spread over it.
  const Eigen::Vector3d centre = sequence.flight().WorldFromCam(0).translation;
  const double pixel = 0.1;
  const cv::Size size(400, 300);
  const auto world_at = [&](int col, int row) {
    return Eigen::Vector2d(centre.x() + (col - size.width / 2) * pixel, centre.y() - (row - size.height / 2) * pixel);
  };
  Rng rng(3);
  std::vector<Eigen::Vector2d> markers;
  for (int m = 0; m < 6; ++m) {
    const Eigen::Vector2d at(rng.Uniform(40, size.width - 40), rng.Uniform(40, size.height - 40));
    const Eigen::Vector2d p = world_at(0, 0) + Eigen::Vector2d(at.x() * pixel, -at.y() * pixel);
    world.PaintMarker(p.x(), p.y(), kMarkerRadiusM);
    markers.push_back(at);
  }
  const cv::Mat ortho = RenderOrthophoto(world, size, pixel, world_at);
  ASSERT_EQ(ortho.size(), size);
  for (const Eigen::Vector2d& at : markers) {
    const Eigen::Vector2d centroid = MarkerCentroid(ortho, at, 1.0, 1.0 / pixel);
    EXPECT_LT((centroid - at).norm(), 0.3) << "marker at " << at.transpose() << " drawn at " << centroid.transpose();
  }
  // Off the world: nothing.
  const cv::Mat outside = RenderOrthophoto(world, cv::Size(4, 4), pixel, [&](int, int) {
    return Eigen::Vector2d(world.max_xy().x() + 10, 0);
  });
  EXPECT_EQ(cv::countNonZero(outside), 0);
}

TEST(Renderer, DepthMatchesTheSurfaceAndBuildingsOcclude) {
  SyntheticOptions options = SmallFlight();
  SyntheticSequence sequence(options, FailureSchedule());
  const SyntheticWorld& world = sequence.world();
  const Camera& camera = sequence.camera();
  ASSERT_FALSE(world.buildings().empty());
  const Building& building = world.buildings().front();
  // Hover above the building's centre, looking straight down.
  const Eigen::Vector3d above(building.centre.x(), building.centre.y(), building.base_z + building.height + 40);
  Eigen::Matrix3d world_from_cam_r;
  world_from_cam_r << 0, -1, 0, -1, 0, 0, 0, 0, -1;
  const Rigid3d world_from_cam(Eigen::Quaterniond(world_from_cam_r), above);
  cv::Mat depth;
  Renderer(world, camera).Render(world_from_cam.Inverse(), &depth);
  // The roof, not the ground below it, is at the image centre.
  EXPECT_NEAR(depth.at<float>(camera.height() / 2, camera.width() / 2), 40.0, 0.05);
  // Elsewhere, every pixel's depth puts its point on the terrain or a building.
  Rng rng(9);
  int on_terrain = 0;
  for (int i = 0; i < 300; ++i) {
    const int x = rng.UniformInt(0, camera.width() - 1), y = rng.UniformInt(0, camera.height() - 1);
    const float d = depth.at<float>(y, x);
    ASSERT_GT(d, 0.0f);
    const Eigen::Vector3d p = world_from_cam * (camera.PixelToRay(Eigen::Vector2d(x, y)) *
                                                (d / camera.PixelToRay(Eigen::Vector2d(x, y)).z()));
    const double above_terrain = p.z() - world.TerrainHeight(p.x(), p.y());
    if (std::abs(above_terrain) < 0.02)
      ++on_terrain;
    else
      EXPECT_GT(above_terrain, 0.0) << "a point below the terrain at pixel " << x << "," << y;
  }
  EXPECT_GT(on_terrain, 100);
}

TEST(Renderer, RendersDistortedCamerasThroughTheModel) {
  SyntheticOptions options = SmallFlight();
  options.world.num_buildings = 0;
  SyntheticSequence sequence(options, FailureSchedule());
  SyntheticWorld& world = sequence.mutable_world();
  const Camera distorted = Camera::Pinhole(640, 480, 450, 450, 319.5, 239.5, -0.2, 0.05, 0.001, -0.0005);
  const Rigid3d world_from_cam = sequence.flight().WorldFromCam(10);
  // A marker towards a corner, where distortion moves it most.
  const Eigen::Vector2d target(120, 90);
  const Eigen::Vector3d ray = world_from_cam.rotation * distorted.PixelToRay(target);
  Eigen::Vector3d point;
  double z = 0;
  for (int it = 0; it < 50; ++it) {
    point = world_from_cam.translation + ray * ((z - world_from_cam.translation.z()) / ray.z());
    z = world.TerrainHeight(point.x(), point.y());
  }
  point.z() = z;
  world.PaintMarker(point.x(), point.y(), kMarkerRadiusM);
  const cv::Mat image = Renderer(world, distorted).Render(world_from_cam.Inverse());
  const Eigen::Vector2d projected = *distorted.Project(world_from_cam.Inverse() * point);
  const double depth = (world_from_cam.Inverse() * point).z();
  EXPECT_LT((MarkerCentroid(image, projected, depth, distorted.fx()) - projected).norm(), 0.5);
}

// The horizontal distance from a point to a building's footprint (0 inside it).
double FootprintDistance(const Building& b, const Eigen::Vector2d& p) {
  const Eigen::Vector2d ax(std::cos(b.yaw), std::sin(b.yaw)), ay(-ax.y(), ax.x());
  const Eigen::Vector2d d = p - b.centre;
  return Eigen::Vector2d(std::max(std::abs(d.dot(ax)) - b.half_length, 0.0),
                         std::max(std::abs(d.dot(ay)) - b.half_width, 0.0))
      .norm();
}

TEST(SyntheticWorld, NoBuildingStandsWhereTheCameraPassesBelowItsRoof) {
  // A low flight through a crowded town: every camera centre that is below a roof keeps 3 m from
  // that building; a route above every roof leaves the town as it is without one.
  SyntheticOptions options;
  options.flight.num_frames = 300;
  options.flight.num_strips = 2;
  options.flight.strip_length_m = 150;
  options.flight.altitude_m = 8;
  options.flight.camera_pitch_deg = 70;
  options.world.num_buildings = 60;
  const SyntheticSequence low(options, FailureSchedule());
  int below_a_roof = 0;
  for (const Building& b : low.world().buildings()) {
    for (const Rigid3d& pose : low.flight().world_from_cam()) {
      if (pose.translation.z() >= b.base_z + b.height + 2) continue;
      ++below_a_roof;
      ASSERT_GE(FootprintDistance(b, pose.translation.head<2>()), 3.0 - 1e-9)
          << "a building of " << b.height << " m stands in the way of a camera " << pose.translation.z() << " m up";
    }
  }
  EXPECT_GT(below_a_roof, 0) << "the flight passes no building below its roof: the test proves nothing";
  // Without a route, or above every roof, the same town.
  const SyntheticWorld& world = low.world();
  const SyntheticWorld anywhere(options.world, 5, world.min_xy(), world.max_xy());
  WorldRoute high;
  for (const Rigid3d& pose : low.flight().world_from_cam())
    high.camera_centres.push_back(pose.translation + Eigen::Vector3d(0, 0, 40));
  const SyntheticWorld above(options.world, 5, world.min_xy(), world.max_xy(), high);
  ASSERT_EQ(above.buildings().size(), anywhere.buildings().size());
  for (size_t i = 0; i < above.buildings().size(); ++i) {
    EXPECT_EQ(above.buildings()[i].centre, anywhere.buildings()[i].centre);
  }
}

TEST(SyntheticWorld, ACarsRoadIsPavedAndLinedWithBuildingsThatKeepOffIt) {
  SyntheticOptions options;
  options.flight.path = "road";
  options.flight.num_frames = 200;
  options.flight.fps = 10;
  options.flight.num_strips = 2;
  options.flight.strip_length_m = 80;
  options.flight.altitude_m = 1.5;
  options.flight.camera_pitch_deg = 88;
  options.world.relief_m = 0;
  const SyntheticSequence road(options, FailureSchedule());
  const auto& centres = road.flight().world_from_cam();
  int beside_the_road = 0;
  for (const Building& b : road.world().buildings()) {
    double nearest = 1e9;
    for (const Rigid3d& pose : centres) nearest = std::min(nearest, FootprintDistance(b, pose.translation.head<2>()));
    ASSERT_GE(nearest, 5.5 - 1e-9) << "a building on the road or its pavement";
    beside_the_road += nearest < 15;
  }
  EXPECT_GE(beside_the_road, 6) << "a street: buildings along both sides of 200 m of road";
  // The asphalt under the car is dark, the pavement beside it light.
  const MipTexture& ground = road.world().ground();
  const Eigen::Vector2d on_road = centres[50].translation.head<2>();
  const auto texel_at = [&](const Eigen::Vector2d& w) {
    const Eigen::Vector2d t = (w - road.world().min_xy()) / ground.texel_m;
    return static_cast<int>(ground.levels[3].at<uint8_t>(static_cast<int>(t.y()) / 8, static_cast<int>(t.x()) / 8));
  };
  EXPECT_LT(texel_at(on_road + Eigen::Vector2d(0, 1.5)), texel_at(on_road + Eigen::Vector2d(0, 5.5)) - 30);
}

TEST(SyntheticSequence, IsDeterministicFromTheSeed) {
  SyntheticOptions options = SmallFlight();
  SyntheticSequence a(options, FailureSchedule());
  SyntheticSequence b(options, FailureSchedule());
  EXPECT_EQ(cv::norm(a.RenderFrame(7), b.RenderFrame(7), cv::NORM_INF), 0);
  options.seed = 2;
  SyntheticSequence c(options, FailureSchedule());
  EXPECT_GT(cv::norm(a.RenderFrame(7), c.RenderFrame(7), cv::NORM_L1), 1e5);
}

TEST(SyntheticSequence, ImagesHaveTextureEverywhere) {
  SyntheticSequence sequence(SmallFlight(), FailureSchedule());
  const cv::Mat image = sequence.RenderFrame(20);
  // Each 80x80 block has contrast: features can be found all over the image.
  for (int y = 0; y + 80 <= image.rows; y += 80) {
    for (int x = 0; x + 80 <= image.cols; x += 80) {
      cv::Scalar mean, stddev;
      cv::meanStdDev(image(cv::Rect(x, y, 80, 80)), mean, stddev);
      EXPECT_GT(stddev[0], 8.0) << "flat block at " << x << "," << y;
    }
  }
}

TEST(SyntheticSequence, HazeFadesTheFarGroundOfAForwardCamera) {
  SyntheticOptions options = SmallFlight();
  options.noise_sigma = 0;
  options.flight.altitude_m = 15;
  options.flight.camera_pitch_deg = 80;
  const auto contrast = [](const cv::Mat& band) {
    cv::Scalar mean, stddev;
    cv::meanStdDev(band, mean, stddev);
    return stddev[0];
  };
  SyntheticSequence clear(options, FailureSchedule());
  options.world.visibility_m = 300;
  SyntheticSequence hazy(options, FailureSchedule());
  const cv::Mat clear_image = clear.RenderFrame(10), hazy_image = hazy.RenderFrame(10);
  // The horizon is near row 160 (10 degrees above the optical axis). Near the camera (the bottom
  // rows, about 25 m ahead) the haze keeps most of the contrast; just below the horizon (150-300 m
  // ahead) it takes most of it.
  const cv::Rect near(0, 420, 640, 60), far(0, 180, 640, 40);
  EXPECT_LT(contrast(clear_image(cv::Rect(0, 0, 640, 100))), 1.0) << "plain sky above the horizon";
  EXPECT_GT(contrast(hazy_image(near)), 0.6 * contrast(clear_image(near)));
  EXPECT_GT(contrast(clear_image(far)), 5.0);
  EXPECT_LT(contrast(hazy_image(far)), 0.4 * contrast(clear_image(far)));
}

TEST(SyntheticSequence, GustFramesAreBlurred) {
  SyntheticOptions options = SmallFlight();
  options.noise_sigma = 0;  // measure the blur, not the sensor noise
  SyntheticSequence sequence(options, FailureSchedule::Parse("20:5"));
  const auto sharpness = [](const cv::Mat& image) {
    cv::Mat lap;
    cv::Laplacian(image, lap, CV_32F);
    cv::Scalar mean, stddev;
    cv::meanStdDev(lap, mean, stddev);
    return stddev[0];
  };
  EXPECT_LT(sharpness(sequence.RenderFrame(22)), 0.3 * sharpness(sequence.RenderFrame(10)));
}

}  // namespace
}  // namespace stitch
