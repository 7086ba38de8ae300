#pragma once
// A source of camera frames: a dataset on disk, a video, or the synthetic flight. Frames come in
// order through Next(); readers are single-threaded objects owned by whoever plays them.

#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "stitch/geometry/camera.h"
#include "stitch/io/trajectory.h"

namespace stitch {

struct SequenceFrame {
  int index = -1;     // position in the sequence, from 0
  int64_t t_ns = 0;   // capture time
  cv::Mat image;      // CV_8UC1; empty when the frame could not be read (see `error`)
  std::string error;  // why `image` is empty, e.g. "rgb/17.png: not a readable image"
};

class ImageSequence {
 public:
  virtual ~ImageSequence() = default;

  // Human-readable: kind, path and length.
  virtual std::string description() const = 0;
  // Number of frames, or -1 when unknown (a live stream).
  virtual int size() const = 0;
  virtual const Camera& camera() const = 0;
  virtual double nominal_fps() const = 0;
  // Ground-truth world_from_cam; empty when the sequence has none.
  virtual const Trajectory& ground_truth() const = 0;
  // The next frame in order; false at the end. A frame whose image cannot be read is returned
  // with an empty image and `error` set, so the caller can count it and go on.
  virtual bool Next(SequenceFrame* frame) = 0;
  // A live camera: frames come at its rate, whatever the consumer does (it is not to be paced).
  virtual bool live() const { return false; }
  // The file frame `index` is read from, for sequences of image files; empty otherwise (a video,
  // a rendered flight, a camera).
  virtual std::string image_path(int /*index*/) const { return {}; }
  // Frames a live source captured but replaced by a newer one before Next() took them.
  virtual int64_t dropped_at_source() const { return 0; }
};

struct SequenceOptions {
  std::string calibration_path;  // overrides the calibration found with the data
  double fps = 0.0;              // frame rate where the data has no timestamps (0: 30 Hz)
  int start_frame = 0;           // skip this many frames at the start
  int max_frames = -1;           // stop after this many frames (-1: all)
  // A video file's frames of at least this many pixels are decoded without the deblocking filter
  // (VideoDecoder; default: never).
  int64_t video_skip_deblocking_from_pixels = std::numeric_limits<int64_t>::max();
};

// What kind of data is at `path`: "tum", "euroc", "kitti", "folder" or "video".
// Throws stitch::Error with what was expected when the path is none of them.
std::string DetectDatasetKind(const std::string& path);

// One image file of a sequence and its time.
struct ImageEntry {
  int64_t t_ns = 0;
  std::string path;
};

// An image folder's images as OpenDataset plays them: each image's time (from its file name, or
// 1/fps apart; fps 0: 30 Hz) and path, in time order. Throws stitch::Error for a folder without
// images.
std::vector<ImageEntry> FolderImageTimes(const std::string& folder, double fps = 0.0);

// Opens a dataset of the detected kind. Throws stitch::Error for a missing folder, a missing or
// wrong calibration, or a first image that cannot be read.
std::unique_ptr<ImageSequence> OpenDataset(const std::string& path, const SequenceOptions& options = {});

// Ground truth in the layouts datasets ship it, detected: TUM ("timestamp tx ty tz qx qy qz qw"),
// KITTI odometry poses (12 numbers a line, one line per frame; the times come from `kitti_times`,
// else from the KITTI layout's sequences/NN/times.txt beside poses/NN.txt), or EuRoC's
// state_groundtruth_estimate0/data.csv (the body's poses, moved onto the camera with cam0/sensor.yaml's
// T_BS when it is there). Throws stitch::Error naming the file and what was expected.
Trajectory ReadGroundTruth(const std::string& path, const std::string& kitti_times = "");

}  // namespace stitch
