#pragma once
// The embedded default sequence: the survey flight over the synthetic world, rendered on demand,
// with scheduled gusts (heavy motion blur while the UAV is knocked off course).

#include <memory>
#include <string>

#include "stitch/io/image_sequence.h"
#include "stitch/synthetic/camera_imperfections.h"
#include "stitch/synthetic/flight.h"
#include "stitch/synthetic/gnss_receiver.h"
#include "stitch/synthetic/renderer.h"
#include "stitch/synthetic/world.h"

namespace stitch {

struct SyntheticOptions {
  int seed = 1;
  int world_seed = 0;  // 0: the world from `seed` too
  int width = 640;
  int height = 480;
  double focal_px = 450.0;
  double noise_sigma = 2.0;          // sensor noise, grey levels
  CameraImperfectionOptions camera;  // a real camera's flaws, each off by default
  FlightOptions flight;
  GustOptions gust;
  WorldOptions world;
  GnssReceiverOptions gnss;  // the aircraft's GNSS receiver

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("seed", seed, "scene, flight and noise are deterministic from this");
    v("world_seed", world_seed,
      "the scene from this seed instead (0: from seed): another flight over the same ground, e.g. for --map");
    v("width", width, "image width, pixels");
    v("height", height, "image height, pixels");
    v("focal_px", focal_px, "focal length, pixels (pinhole; distortion: camera.lens_k1, lens_k2)");
    v("noise_sigma", noise_sigma, "sensor noise, grey levels");
    v("camera", camera, "a real camera's flaws, each off by default");
    v("flight", flight, "the survey path");
    v("gust", gust, "what a scheduled gust does");
    v("world", world, "the terrain, textures and buildings");
    v("gnss", gnss, "the aircraft's GNSS receiver: fixes of the true positions with noise, dropouts, jumps");
  }
  bool Check(std::string* why) const;
  Camera MakeCamera() const;
};

class SyntheticSequence : public ImageSequence {
 public:
  // Builds the world (about a second) and the flight. Throws stitch::Error on invalid options.
  SyntheticSequence(const SyntheticOptions& options, const FailureSchedule& gusts);

  std::string description() const override;
  int size() const override { return flight_.num_frames(); }
  const Camera& camera() const override { return camera_; }
  double nominal_fps() const override { return options_.flight.fps; }
  const Trajectory& ground_truth() const override { return ground_truth_; }
  bool Next(SequenceFrame* frame) override;

  // Random access, for tests and tools. With a rolling shutter, `depth` is that of the first
  // rows' pose.
  cv::Mat RenderFrame(int index, cv::Mat* depth = nullptr) const;
  // The world seen from any pose (no gust blur), with the sensor noise drawn from `noise_key`.
  cv::Mat RenderAt(const Rigid3d& world_from_cam, uint64_t noise_key, cv::Mat* depth = nullptr) const;
  const FlightPlan& flight() const { return flight_; }
  const SyntheticWorld& world() const { return *world_; }
  SyntheticWorld& mutable_world() { return *world_; }

 private:
  void AddSensorNoise(cv::Mat* image, uint64_t key) const;
  // Frame `index` through a rolling shutter: bands of rows, each rendered at the pose of its
  // rows' mid readout time (the frame's time is its first row's).
  cv::Mat RenderRollingShutter(int index, cv::Mat* depth) const;
  // The blur of the camera's own motion over the exposure at frame `index`: length (pixels) and
  // direction of the image's centre's motion; `depth` is the frame's.
  std::pair<double, double> ExposureBlur(int index, const cv::Mat& depth) const;

  SyntheticOptions options_;
  Camera camera_;
  FlightPlan flight_;
  std::unique_ptr<SyntheticWorld> world_;
  std::unique_ptr<Renderer> renderer_;
  ImageImperfections imperfections_;
  Trajectory ground_truth_;
  int next_ = 0;
};

}  // namespace stitch
