#include "stitch/synthetic/synthetic_sequence.h"

#include <algorithm>
#include <cmath>
#include <optional>

#include <opencv2/imgproc.hpp>

#include "stitch/util/error.h"
#include "stitch/util/options.h"
#include "stitch/util/rng.h"

namespace stitch {

bool SyntheticOptions::Check(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (world_seed < 0) return fail("synthetic.world_seed must be >= 0 (0: the world from synthetic.seed)");
  if (width < 32 || width > 8192 || height < 32 || height > 8192) {
    return fail("synthetic.width and height must be in [32, 8192]");
  }
  if (!(focal_px > 1 && focal_px < 100000)) return fail("synthetic.focal_px must be in (1, 100000)");
  if (!(noise_sigma >= 0 && noise_sigma <= 50)) return fail("synthetic.noise_sigma must be in [0, 50]");
  return camera.Check(why) && flight.Check(why) && gust.Check(why) && world.Check(why);
}

Camera SyntheticOptions::MakeCamera() const {
  return Camera::Pinhole(width, height, focal_px, focal_px, (width - 1) / 2.0, (height - 1) / 2.0, camera.lens_k1,
                         camera.lens_k2);
}

SyntheticSequence::SyntheticSequence(const SyntheticOptions& options, const FailureSchedule& gusts)
    : options_((CheckOptions(options, "synthetic"), options)),
      camera_(options.MakeCamera()),
      flight_(options.flight, options.gust, camera_, gusts, static_cast<uint64_t>(options.seed)),
      imperfections_(options.camera, options.width, options.height, options.flight.num_frames, options.flight.fps,
                     static_cast<uint64_t>(options.seed)) {
  // The world is built around a flight: this one, or with world_seed the one that seed flies
  // (same plan and gust schedule), so that another seed's flight crosses the very same ground.
  const bool other_world = options.world_seed > 0 && options.world_seed != options.seed;
  const uint64_t world_seed = static_cast<uint64_t>(other_world ? options.world_seed : options.seed);
  std::optional<FlightPlan> world_flight;
  if (other_world) world_flight.emplace(options.flight, options.gust, camera_, gusts, world_seed);
  const FlightPlan& around = world_flight ? *world_flight : flight_;
  WorldRoute route;
  for (const Rigid3d& world_from_cam : around.world_from_cam())
    route.camera_centres.push_back(world_from_cam.translation);
  route.paved = options_.flight.path == "road";
  world_ = std::make_unique<SyntheticWorld>(options_.world, world_seed * 7919 + 17, around.min_ground_xy(),
                                            around.max_ground_xy(), route);
  renderer_ = std::make_unique<Renderer>(*world_, camera_);
  std::vector<StampedPose> poses;
  for (int i = 0; i < flight_.num_frames(); ++i) {
    poses.push_back({flight_.TimestampNs(i), flight_.WorldFromCam(i)});
  }
  ground_truth_ = Trajectory(std::move(poses));
}

std::string SyntheticSequence::description() const {
  return Str() << "synthetic UAV survey (seed " << options_.seed
               << (options_.world_seed > 0 && options_.world_seed != options_.seed
                       ? ", the world of seed " + std::to_string(options_.world_seed)
                       : std::string())
               << ", " << flight_.num_frames() << " frames, " << options_.width << "x" << options_.height << ", gusts "
               << flight_.gusts().ToString() << ")";
}

void SyntheticSequence::AddSensorNoise(cv::Mat* image, uint64_t key) const {
  if (!(options_.noise_sigma > 0)) return;
  cv::Mat noise(image->size(), CV_16S);
  cv::RNG rng(HashU64(static_cast<uint64_t>(options_.seed), key, 0x4e));
  rng.fill(noise, cv::RNG::NORMAL, 0.0, options_.noise_sigma);
  cv::Mat noisy;
  image->convertTo(noisy, CV_16S);
  noisy += noise;
  noisy.convertTo(*image, CV_8U);
}

cv::Mat SyntheticSequence::RenderFrame(int index, cv::Mat* depth) const {
  const CameraImperfectionOptions& flaws = options_.camera;
  cv::Mat own_depth;
  if (!depth && flaws.exposure_time_ms > 0) depth = &own_depth;
  cv::Mat image = flaws.rolling_shutter_line_us > 0 ? RenderRollingShutter(index, depth)
                                                    : renderer_->Render(flight_.WorldFromCam(index).Inverse(), depth);
  const auto [blur_px, blur_angle] = flight_.GustBlur(index);
  if (blur_px > 0) {
    ApplyMotionBlur(&image, blur_px, blur_angle);
  } else if (flaws.exposure_time_ms > 0) {
    const auto [length_px, angle] = ExposureBlur(index, *depth);
    if (length_px >= 1) ApplyMotionBlur(&image, length_px, angle);
  }
  imperfections_.ApplyOptics(index, &image);
  AddSensorNoise(&image, static_cast<uint64_t>(index));
  imperfections_.ApplyCompression(&image);
  return image;
}

cv::Mat SyntheticSequence::RenderRollingShutter(int index, cv::Mat* depth) const {
  const Rigid3d now = flight_.WorldFromCam(index);
  const Rigid3d next = flight_.WorldFromCam(std::min(index + 1, flight_.num_frames() - 1));
  const int height = options_.height, bands = std::min(options_.camera.rolling_shutter_bands, height);
  cv::Mat image(height, options_.width, CV_8UC1);
  for (int band = 0; band < bands; ++band) {
    const int first = band * height / bands, end = (band + 1) * height / bands;
    // The band's mid row is read this many frames after the first row.
    const double frames =
        0.5 * (first + end - 1) * options_.camera.rolling_shutter_line_us * 1e-6 * options_.flight.fps;
    Rigid3d world_from_cam;
    world_from_cam.rotation = now.rotation.slerp(frames, next.rotation);
    world_from_cam.translation = now.translation + frames * (next.translation - now.translation);
    const cv::Mat rendered = renderer_->Render(world_from_cam.Inverse(), band == 0 ? depth : nullptr);
    rendered.rowRange(first, end).copyTo(image.rowRange(first, end));
  }
  return image;
}

std::pair<double, double> SyntheticSequence::ExposureBlur(int index, const cv::Mat& depth) const {
  // The scene's depth about the image's centre (what is drawn there), else the flight's height.
  const int w = options_.width, h = options_.height;
  double depth_sum = 0;
  int depth_count = 0;
  if (!depth.empty()) {
    const cv::Mat centre = depth(cv::Rect(w / 4, h / 4, w / 2, h / 2));
    for (int y = 0; y < centre.rows; y += 4) {
      for (int x = 0; x < centre.cols; x += 4) {
        const float z = centre.at<float>(y, x);
        if (z > 0) {
          depth_sum += z;
          ++depth_count;
        }
      }
    }
  }
  const double z = depth_count > 0 ? depth_sum / depth_count : options_.flight.altitude_m;
  // Where the centre's scene point is one frame on (or was one frame before, at the last frame).
  const int other = index + 1 < flight_.num_frames() ? index + 1 : std::max(0, index - 1);
  const Eigen::Vector3d world = flight_.WorldFromCam(index) * Eigen::Vector3d(0, 0, z);
  const Eigen::Vector3d seen = flight_.WorldFromCam(other).Inverse() * world;
  if (seen.z() <= 0 || other == index) return {0, 0};
  const Eigen::Vector2d moved(options_.focal_px * seen.x() / seen.z(), options_.focal_px * seen.y() / seen.z());
  const double per_exposure = options_.camera.exposure_time_ms * 1e-3 * options_.flight.fps;
  return {moved.norm() * per_exposure, std::atan2(moved.y(), moved.x())};
}

cv::Mat SyntheticSequence::RenderAt(const Rigid3d& world_from_cam, uint64_t noise_key, cv::Mat* depth) const {
  cv::Mat image = renderer_->Render(world_from_cam.Inverse(), depth);
  AddSensorNoise(&image, noise_key);
  return image;
}

bool SyntheticSequence::Next(SequenceFrame* frame) {
  if (next_ >= flight_.num_frames()) return false;
  frame->index = next_;
  frame->t_ns = flight_.TimestampNs(next_);
  frame->error.clear();
  frame->image = RenderFrame(next_);
  ++next_;
  return true;
}

}  // namespace stitch
