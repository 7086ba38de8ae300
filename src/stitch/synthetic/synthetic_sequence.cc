#include "stitch/synthetic/synthetic_sequence.h"

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
  if (width < 32 || width > 8192 || height < 32 || height > 8192) {
    return fail("synthetic.width and height must be in [32, 8192]");
  }
  if (!(focal_px > 1 && focal_px < 100000)) return fail("synthetic.focal_px must be in (1, 100000)");
  if (!(noise_sigma >= 0 && noise_sigma <= 50)) return fail("synthetic.noise_sigma must be in [0, 50]");
  return flight.Check(why) && gust.Check(why) && world.Check(why);
}

Camera SyntheticOptions::MakeCamera() const {
  return Camera::Pinhole(width, height, focal_px, focal_px, (width - 1) / 2.0, (height - 1) / 2.0);
}

SyntheticSequence::SyntheticSequence(const SyntheticOptions& options, const FailureSchedule& gusts)
    : options_((CheckOptions(options, "synthetic"), options)),
      camera_(options.MakeCamera()),
      flight_(options.flight, options.gust, camera_, gusts, static_cast<uint64_t>(options.seed)) {
  WorldRoute route;
  for (const Rigid3d& world_from_cam : flight_.world_from_cam())
    route.camera_centres.push_back(world_from_cam.translation);
  route.paved = options_.flight.path == "road";
  world_ = std::make_unique<SyntheticWorld>(options_.world, static_cast<uint64_t>(options_.seed) * 7919 + 17,
                                            flight_.min_ground_xy(), flight_.max_ground_xy(), route);
  renderer_ = std::make_unique<Renderer>(*world_, camera_);
  std::vector<StampedPose> poses;
  for (int i = 0; i < flight_.num_frames(); ++i) {
    poses.push_back({flight_.TimestampNs(i), flight_.WorldFromCam(i)});
  }
  ground_truth_ = Trajectory(std::move(poses));
}

std::string SyntheticSequence::description() const {
  return Str() << "synthetic UAV survey (seed " << options_.seed << ", " << flight_.num_frames() << " frames, "
               << options_.width << "x" << options_.height << ", gusts " << flight_.gusts().ToString() << ")";
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
  cv::Mat image = renderer_->Render(flight_.WorldFromCam(index).Inverse(), depth);
  const auto [blur_px, blur_angle] = flight_.GustBlur(index);
  if (blur_px > 0) ApplyMotionBlur(&image, blur_px, blur_angle);
  AddSensorNoise(&image, static_cast<uint64_t>(index));
  return image;
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
