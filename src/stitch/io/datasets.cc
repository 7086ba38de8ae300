// Readers for TUM RGB-D, EuRoC MAV, KITTI odometry, image folders and video files.

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "stitch/io/calibration.h"
#include "stitch/io/image_sequence.h"
#include "stitch/io/video_decoder.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "stitch/util/options.h"
#include "stitch/util/text_file.h"
#include "stitch/util/time.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

bool IsImageFile(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  return ext == ".png" || ext == ".jpg" || ext == ".jpeg" || ext == ".pgm" || ext == ".bmp" || ext == ".tif" ||
         ext == ".tiff" || ext == ".ppm";
}

bool IsVideoFile(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  return ext == ".mp4" || ext == ".avi" || ext == ".mkv" || ext == ".mov" || ext == ".webm" || ext == ".m4v" ||
         ext == ".mpg" || ext == ".mpeg";
}

cv::Mat ReadGray(const std::string& path, std::string* error) {
  cv::Mat image;
  try {
    image = cv::imread(path, cv::IMREAD_GRAYSCALE);
  } catch (const cv::Exception& e) {
    image.release();
  }
  if (image.empty()) {
    *error = fs::exists(path) ? path + ": not a readable image" : path + ": file not found";
    return {};
  }
  if (image.depth() != CV_8U) image.convertTo(image, CV_8U);
  return image;
}

std::string FirstExisting(const std::vector<fs::path>& candidates) {
  for (const auto& c : candidates) {
    if (fs::exists(c)) return c.string();
  }
  return "";
}

// Reads the first image to learn the size, then loads and checks the calibration.
Camera CameraForImages(const std::vector<ImageEntry>& images, const std::string& calibration_path,
                       const std::string& source) {
  if (images.empty()) throw Error(source + ": no images");
  std::string error;
  const cv::Mat first = ReadGray(images.front().path, &error);
  if (first.empty()) throw Error(source + ": cannot read the first image: " + error);
  return LoadCalibration(calibration_path, first.cols, first.rows);
}

// Frames listed up front (TUM, EuRoC, KITTI, image folders).
class ImageListSequence : public ImageSequence {
 public:
  ImageListSequence(std::string description, std::vector<ImageEntry> images, Camera camera, Trajectory ground_truth,
                    double fps)
      : description_(std::move(description)),
        images_(std::move(images)),
        camera_(std::move(camera)),
        // Only what the played frames span: a run of part of a sequence is drawn and evaluated
        // against that part.
        ground_truth_(images_.empty() ? std::move(ground_truth)
                                      : ground_truth.Between(images_.front().t_ns, images_.back().t_ns)),
        fps_(fps) {}

  std::string description() const override { return description_ + " (" + std::to_string(images_.size()) + " frames)"; }
  int size() const override { return static_cast<int>(images_.size()); }
  const Camera& camera() const override { return camera_; }
  double nominal_fps() const override { return fps_; }
  const Trajectory& ground_truth() const override { return ground_truth_; }
  std::string image_path(int index) const override {
    return index >= 0 && index < static_cast<int>(images_.size()) ? images_[index].path : std::string();
  }

  bool Next(SequenceFrame* frame) override {
    if (next_ >= images_.size()) return false;
    const ImageEntry& entry = images_[next_];
    frame->index = static_cast<int>(next_);
    frame->t_ns = entry.t_ns;
    frame->error.clear();
    frame->image = ReadGray(entry.path, &frame->error);
    if (!frame->image.empty() && (frame->image.cols != camera_.width() || frame->image.rows != camera_.height())) {
      frame->error = Str() << entry.path << ": image is " << frame->image.cols << "x" << frame->image.rows
                           << " but the sequence is " << camera_.width() << "x" << camera_.height();
      frame->image.release();
    }
    ++next_;
    return true;
  }

 private:
  std::string description_;
  std::vector<ImageEntry> images_;
  Camera camera_;
  Trajectory ground_truth_;
  double fps_;
  size_t next_ = 0;
};

double FpsFromTimestamps(const std::vector<ImageEntry>& images, double fallback) {
  if (images.size() < 2) return fallback;
  const double span_s = (images.back().t_ns - images.front().t_ns) * 1e-9;
  return span_s > 0 ? (images.size() - 1) / span_s : fallback;
}

// The list as the camera took it: a list out of time order (sorted by name, say: 10.0 before
// 2.0) is played in time order, with a warning; tracking a shuffled sequence goes nowhere.
std::vector<ImageEntry> InTimeOrder(std::vector<ImageEntry> images, const std::string& list) {
  const auto earlier = [](const ImageEntry& a, const ImageEntry& b) { return a.t_ns < b.t_ns; };
  const auto first_out = std::is_sorted_until(images.begin(), images.end(), earlier);
  if (first_out == images.end()) return images;
  const size_t backwards = [&] {
    size_t n = 0;
    for (size_t i = 1; i < images.size(); ++i) n += images[i].t_ns < images[i - 1].t_ns;
    return n;
  }();
  STITCH_LOG(WARNING) << list << " lists its images out of time order (" << backwards << " step"
                      << (backwards == 1 ? "" : "s") << " back in time, the first at entry "
                      << (first_out - images.begin() + 1) << ", " << first_out->path << "); playing them in time order";
  std::stable_sort(images.begin(), images.end(), earlier);
  return images;
}

std::vector<ImageEntry> Slice(std::vector<ImageEntry> images, const SequenceOptions& options) {
  const size_t start = std::min<size_t>(std::max(options.start_frame, 0), images.size());
  images.erase(images.begin(), images.begin() + start);
  if (options.max_frames >= 0 && static_cast<size_t>(options.max_frames) < images.size()) {
    images.resize(options.max_frames);
  }
  return images;
}

// --- TUM RGB-D -----------------------------------------------------------------------------

// Published calibrations of the TUM RGB-D cameras (vision.in.tum.de/data/datasets/rgbd-dataset),
// used when the sequence folder brings none.
std::optional<Camera> TumDefaultCamera(const std::string& folder_name, int width, int height) {
  if (folder_name.find("freiburg1") != std::string::npos) {
    return Camera::Pinhole(width, height, 517.306408, 516.469215, 318.643040, 255.313989, 0.262383, -0.953104,
                           -0.005358, 0.002628, 1.163314);
  }
  if (folder_name.find("freiburg2") != std::string::npos) {
    return Camera::Pinhole(width, height, 520.908620, 521.007327, 325.141442, 249.701764, 0.231222, -0.784899,
                           -0.003257, -0.000105, 0.917205);
  }
  if (folder_name.find("freiburg3") != std::string::npos) {
    return Camera::Pinhole(width, height, 535.4, 539.2, 320.1, 247.6);
  }
  return std::nullopt;
}

std::unique_ptr<ImageSequence> OpenTum(const fs::path& root, const SequenceOptions& options) {
  const fs::path list = root / "rgb.txt";
  std::vector<ImageEntry> images;
  ForEachDataLine(
      list.string(),
      [&](const std::string& line, int line_number) {
        std::istringstream fields(line);
        std::string stamp, file;
        fields >> stamp >> file;
        if (file.empty())
          throw Error(Str() << list.string() << ":" << line_number << ": expected 'timestamp filename'");
        try {
          images.push_back({ParseSecondsToNs(stamp), (root / file).string()});
        } catch (const Error& e) {
          throw Error(Str() << list.string() << ":" << line_number << ": " << e.what());
        }
      },
      " (TUM RGB-D sequences have rgb.txt)");
  images = Slice(InTimeOrder(std::move(images), list.string()), options);
  const std::string folder_name =
      root.filename().empty() ? root.parent_path().filename().string() : root.filename().string();
  std::string calibration = options.calibration_path;
  if (calibration.empty()) calibration = FirstExisting({root / "camera.yaml", root / "calibration.yaml"});
  Camera camera;
  if (!calibration.empty()) {
    camera = CameraForImages(images, calibration, root.string());
  } else {
    std::string error;
    if (images.empty()) throw Error(root.string() + ": rgb.txt lists no images");
    const cv::Mat first = ReadGray(images.front().path, &error);
    if (first.empty()) throw Error(root.string() + ": cannot read the first image: " + error);
    auto known = TumDefaultCamera(folder_name, first.cols, first.rows);
    if (!known) {
      throw Error(root.string() + ": no camera.yaml and the folder name does not say freiburg1/2/3; pass --calib");
    }
    camera = *known;
  }
  Trajectory ground_truth;
  if (fs::exists(root / "groundtruth.txt")) {
    ground_truth = Trajectory::ReadTum((root / "groundtruth.txt").string());
  }
  const double fps = FpsFromTimestamps(images, 30.0);
  return std::make_unique<ImageListSequence>("TUM RGB-D " + root.string(), std::move(images), camera,
                                             std::move(ground_truth), fps);
}

// --- EuRoC MAV -----------------------------------------------------------------------------

Eigen::Matrix4d ReadTBS(const std::string& sensor_yaml) {
  const YAML::Node root = LoadYamlFile(sensor_yaml);
  Eigen::Matrix4d body_from_cam = Eigen::Matrix4d::Identity();
  if (root["T_BS"] && root["T_BS"]["data"]) {
    const auto data = root["T_BS"]["data"].as<std::vector<double>>();
    if (data.size() != 16) throw Error(sensor_yaml + ": T_BS.data must hold 16 numbers");
    for (int i = 0; i < 16; ++i) body_from_cam(i / 4, i % 4) = data[i];
  }
  return body_from_cam;
}

// state_groundtruth_estimate0/data.csv holds world_from_body; the camera is body_from_cam (T_BS).
Trajectory ReadEurocStateGroundTruth(const std::string& path, const Eigen::Matrix4d& body_from_cam) {
  std::vector<StampedPose> poses;
  const Eigen::Matrix3d r_bc = body_from_cam.topLeftCorner<3, 3>();
  const Rigid3d body_from_cam_rigid(Eigen::Quaterniond(r_bc).normalized(), body_from_cam.topRightCorner<3, 1>());
  ForEachDataLine(path, [&](std::string line, int line_number) {
    std::replace(line.begin(), line.end(), ',', ' ');
    std::istringstream fields(line);
    long long t;
    double p[3], q[4];
    fields >> t >> p[0] >> p[1] >> p[2] >> q[0] >> q[1] >> q[2] >> q[3];
    if (!fields) throw Error(Str() << path << ":" << line_number << ": malformed ground-truth line");
    const Rigid3d world_from_body(Eigen::Quaterniond(q[0], q[1], q[2], q[3]).normalized(),
                                  Eigen::Vector3d(p[0], p[1], p[2]));
    poses.push_back({t, world_from_body * body_from_cam_rigid});
  });
  return Trajectory(std::move(poses));
}

std::unique_ptr<ImageSequence> OpenEuroc(const fs::path& given, const SequenceOptions& options) {
  const fs::path mav = fs::exists(given / "mav0") ? given / "mav0" : given;
  const fs::path root = mav.parent_path();
  const fs::path cam = mav / "cam0";
  const fs::path list = cam / "data.csv";
  std::vector<ImageEntry> images;
  ForEachDataLine(
      list.string(),
      [&](const std::string& line, int line_number) {
        const auto comma = line.find(',');
        if (comma == std::string::npos) {
          throw Error(Str() << list.string() << ":" << line_number << ": expected 'timestamp,filename'");
        }
        std::string file = line.substr(comma + 1);
        while (!file.empty() && std::isspace(static_cast<unsigned char>(file.back()))) file.pop_back();
        try {
          images.push_back({std::stoll(line.substr(0, comma)), (cam / "data" / file).string()});
        } catch (const std::exception&) {
          throw Error(Str() << list.string() << ":" << line_number << ": bad timestamp");
        }
      },
      " (EuRoC sequences have mav0/cam0/data.csv)");
  images = Slice(InTimeOrder(std::move(images), list.string()), options);
  const std::string sensor = (cam / "sensor.yaml").string();
  const std::string calibration = options.calibration_path.empty() ? sensor : options.calibration_path;
  const Camera camera = CameraForImages(images, calibration, mav.string());
  Trajectory ground_truth;
  if (fs::exists(root / "groundtruth_cam0.txt")) {
    ground_truth = Trajectory::ReadTum((root / "groundtruth_cam0.txt").string());
  } else if (fs::exists(mav / "state_groundtruth_estimate0" / "data.csv")) {
    ground_truth = ReadEurocStateGroundTruth((mav / "state_groundtruth_estimate0" / "data.csv").string(),
                                             fs::exists(sensor) ? ReadTBS(sensor) : Eigen::Matrix4d::Identity());
  }
  const double fps = FpsFromTimestamps(images, 20.0);
  return std::make_unique<ImageListSequence>("EuRoC " + root.string(), std::move(images), camera,
                                             std::move(ground_truth), fps);
}

// --- KITTI odometry ------------------------------------------------------------------------

// times.txt: one time a line, in seconds, often in exponent form ("1.036e-01"), which
// ParseSecondsToNs rejects on purpose; KITTI's resolution is far coarser than a double's.
std::vector<int64_t> ReadKittiTimes(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw Error(path + ": cannot open (KITTI odometry sequences have times.txt)");
  std::vector<int64_t> times;
  std::string stamp;
  while (in >> stamp) {
    double seconds = 0;
    try {
      seconds = std::stod(stamp);
    } catch (const std::exception&) {
      throw Error(Str() << path << ": line " << times.size() + 1 << ": '" << stamp << "' is not a time in seconds");
    }
    if (!std::isfinite(seconds)) throw Error(Str() << path << ": line " << times.size() + 1 << ": not finite");
    times.push_back(static_cast<int64_t>(std::llround(seconds * 1e9)));
  }
  return times;
}

// poses/NN.txt: one world_from_cam a line, the 3x4 matrix row by row.
std::vector<Rigid3d> ReadKittiPoses(const std::string& path) {
  std::vector<Rigid3d> poses;
  ForEachDataLine(path, [&](const std::string& line, int line_number) {
    std::istringstream fields(line);
    double m[12];
    for (double& v : m) fields >> v;
    std::string extra;
    if (!fields || (fields >> extra)) {
      throw Error(Str() << path << ":" << line_number << ": a KITTI pose line holds 12 numbers");
    }
    Eigen::Matrix3d r;
    r << m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10];
    if (!r.allFinite() || std::abs(r.determinant() - 1.0) > 0.01) {
      throw Error(Str() << path << ":" << line_number << ": not a rotation");
    }
    poses.push_back(Rigid3d(Eigen::Quaterniond(r).normalized(), Eigen::Vector3d(m[3], m[7], m[11])));
  });
  return poses;
}

std::unique_ptr<ImageSequence> OpenKitti(const fs::path& root, const SequenceOptions& options) {
  std::vector<ImageEntry> images;
  char name[32];
  for (const int64_t t_ns : ReadKittiTimes((root / "times.txt").string())) {
    std::snprintf(name, sizeof(name), "%06zu.png", images.size());
    images.push_back({t_ns, (root / "image_0" / name).string()});
  }
  images = Slice(std::move(images), options);
  const std::string calibration =
      options.calibration_path.empty() ? (root / "calib.txt").string() : options.calibration_path;
  const Camera camera = CameraForImages(images, calibration, root.string());
  Trajectory ground_truth;
  const fs::path sequence_dir = fs::absolute(root).lexically_normal();
  const std::string sequence_name = sequence_dir.filename().empty() ? sequence_dir.parent_path().filename().string()
                                                                    : sequence_dir.filename().string();
  const fs::path poses = sequence_dir.parent_path().parent_path() / "poses" / (sequence_name + ".txt");
  if (fs::exists(poses)) {
    const std::vector<Rigid3d> gt = ReadKittiPoses(poses.string());
    // Poses are one per frame of the full sequence; keep those of the frames we play.
    std::vector<StampedPose> kept;
    for (size_t k = 0; k < images.size(); ++k) {
      const size_t full_index = k + std::max(options.start_frame, 0);
      if (full_index < gt.size()) kept.push_back({images[k].t_ns, gt[full_index]});
    }
    ground_truth = Trajectory(std::move(kept));
  }
  const double fps = FpsFromTimestamps(images, 10.0);
  return std::make_unique<ImageListSequence>("KITTI " + root.string(), std::move(images), camera,
                                             std::move(ground_truth), fps);
}

// --- Image folder --------------------------------------------------------------------------

// Timestamps from file names when every name is a number: integers of 16+ digits are
// nanoseconds (EuRoC style), names with a '.' are seconds. Otherwise frames are 1/fps apart.
std::vector<ImageEntry> TimestampFolder(const std::vector<fs::path>& files, double fps) {
  bool all_ns = true, all_seconds = true;
  for (const auto& f : files) {
    const std::string stem = f.stem().string();
    const bool digits = !stem.empty() && std::all_of(stem.begin(), stem.end(), [](char c) {
      return std::isdigit(static_cast<unsigned char>(c));
    });
    all_ns = all_ns && digits && stem.size() >= 16;
    bool seconds = stem.find('.') != std::string::npos;
    if (seconds) {
      try {
        ParseSecondsToNs(stem);
      } catch (const Error&) {
        seconds = false;
      }
    }
    all_seconds = all_seconds && seconds;
  }
  std::vector<ImageEntry> images;
  for (size_t i = 0; i < files.size(); ++i) {
    const std::string stem = files[i].stem().string();
    int64_t t_ns;
    if (all_ns) {
      t_ns = std::stoll(stem);
    } else if (all_seconds) {
      t_ns = ParseSecondsToNs(stem);
    } else {
      t_ns = static_cast<int64_t>(std::llround(i * 1e9 / fps));
    }
    images.push_back({t_ns, files[i].string()});
  }
  std::stable_sort(images.begin(), images.end(),
                   [](const ImageEntry& a, const ImageEntry& b) { return a.t_ns < b.t_ns; });
  return images;
}

}  // namespace

std::vector<ImageEntry> FolderImageTimes(const std::string& folder, double fps) {
  const fs::path root(folder);
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(root)) {
    if (entry.is_regular_file() && IsImageFile(entry.path())) files.push_back(entry.path());
  }
  if (files.empty()) throw Error(root.string() + ": no images (.png, .jpg, .pgm, ...) in this folder");
  std::sort(files.begin(), files.end());
  return TimestampFolder(files, fps > 0 ? fps : 30.0);
}

namespace {

std::unique_ptr<ImageSequence> OpenImageFolder(const fs::path& root, const SequenceOptions& options) {
  const double fps = options.fps > 0 ? options.fps : 30.0;
  std::vector<ImageEntry> images = Slice(FolderImageTimes(root.string(), fps), options);
  std::string calibration = options.calibration_path;
  if (calibration.empty()) {
    calibration = FirstExisting({root / "camera.yaml", root / "calibration.yaml", root.parent_path() / "camera.yaml"});
  }
  if (calibration.empty()) {
    throw Error(root.string() + ": no calibration; put camera.yaml beside the images or pass --calib FILE");
  }
  const Camera camera = CameraForImages(images, calibration, root.string());
  Trajectory ground_truth;
  const std::string gt = FirstExisting({root / "groundtruth.txt", root.parent_path() / "groundtruth.txt"});
  if (!gt.empty()) ground_truth = Trajectory::ReadTum(gt);
  const double sequence_fps = FpsFromTimestamps(images, fps);
  return std::make_unique<ImageListSequence>("image folder " + root.string(), std::move(images), camera,
                                             std::move(ground_truth), sequence_fps);
}

// --- Video file ----------------------------------------------------------------------------

class VideoSequence : public ImageSequence {
 public:
  VideoSequence(const fs::path& path, const SequenceOptions& options)
      : path_(path.string()), decoder_(path_, options.video_skip_deblocking_from_pixels) {
    fps_ = options.fps > 0 ? options.fps : decoder_.fps();
    if (!(fps_ > 0 && fps_ < 1000)) fps_ = 30.0;
    const int64_t count = decoder_.frame_count();
    total_ = count > 0 && count < std::numeric_limits<int>::max() ? static_cast<int>(count) : -1;
    for (int i = 0; i < options.start_frame; ++i) {
      if (!decoder_.Skip()) break;
      ++source_index_;
    }
    if (total_ >= 0) total_ = std::max(0, total_ - options.start_frame);
    if (options.max_frames >= 0 && (total_ < 0 || options.max_frames < total_)) total_ = options.max_frames;
    max_frames_ = options.max_frames;
    // Read one frame now to learn the size and check the calibration.
    if (!ReadFrame(&pending_)) throw Error(path_ + ": the video has no readable frame");
    has_pending_ = true;
    std::string calibration = options.calibration_path;
    if (calibration.empty()) {
      calibration = FirstExisting({fs::path(path_).replace_extension(".yaml"), path.parent_path() / "camera.yaml"});
    }
    if (calibration.empty()) {
      throw Error(path_ + ": no calibration; pass --calib FILE or put " +
                  fs::path(path_).replace_extension(".yaml").filename().string() + " beside it");
    }
    camera_ = LoadCalibration(calibration, pending_.image.cols, pending_.image.rows);
    // Ground truth beside the clip: flight.groundtruth.txt for flight.mp4 (what `stitch render
    // --out flight.mp4` writes), else the folder's groundtruth.txt.
    const std::string truth =
        FirstExisting({fs::path(path_).replace_extension(".groundtruth.txt"), path.parent_path() / "groundtruth.txt"});
    if (!truth.empty()) ground_truth_ = Trajectory::ReadTum(truth);
  }

  std::string description() const override {
    return "video " + path_ + (total_ >= 0 ? " (" + std::to_string(total_) + " frames)" : "");
  }
  int size() const override { return total_; }
  const Camera& camera() const override { return camera_; }
  double nominal_fps() const override { return fps_; }
  const Trajectory& ground_truth() const override { return ground_truth_; }

  bool Next(SequenceFrame* frame) override {
    if (max_frames_ >= 0 && emitted_ >= max_frames_) return false;
    if (has_pending_) {
      *frame = pending_;
      has_pending_ = false;
    } else if (!ReadFrame(frame)) {
      return false;
    }
    frame->index = emitted_++;
    return true;
  }

 private:
  bool ReadFrame(SequenceFrame* frame) {
    int64_t clip_ns = -1;
    if (!decoder_.Read(&frame->image, &clip_ns)) return false;
    frame->error.clear();
    frame->t_ns = ClipTimeNs(clip_ns);
    last_t_ns_ = frame->t_ns;
    ++source_index_;
    return true;
  }

  // The frame's presentation time in the clip (a variable frame rate kept). Where the stream
  // gives none, or one that goes back or stands still, the previous frame's time plus one frame
  // at the nominal rate.
  int64_t ClipTimeNs(int64_t clip_ns) const {
    const int64_t by_rate = last_t_ns_ < 0 ? static_cast<int64_t>(std::llround(source_index_ * 1e9 / fps_))
                                           : last_t_ns_ + static_cast<int64_t>(std::llround(1e9 / fps_));
    if (clip_ns < 0) return by_rate;
    const bool plausible = last_t_ns_ >= 0 ? clip_ns > last_t_ns_ : (clip_ns > 0 || source_index_ == 0);
    return plausible ? clip_ns : by_rate;
  }

  std::string path_;
  VideoDecoder decoder_;
  Camera camera_;
  Trajectory ground_truth_;
  double fps_ = 30.0;
  int total_ = -1;
  int max_frames_ = -1;
  int source_index_ = 0;
  int64_t last_t_ns_ = -1;
  int emitted_ = 0;
  SequenceFrame pending_;
  bool has_pending_ = false;
};

}  // namespace

std::string DetectDatasetKind(const std::string& path_text) {
  const fs::path path(path_text);
  if (!fs::exists(path)) throw Error(path_text + ": no such file or folder");
  if (fs::is_regular_file(path)) {
    if (IsVideoFile(path)) return "video";
    throw Error(path_text + ": a file, but not a video stitch knows (.mp4, .avi, .mkv, .mov, ...)");
  }
  if (fs::exists(path / "rgb.txt")) return "tum";
  if (fs::exists(path / "mav0" / "cam0" / "data.csv") || fs::exists(path / "cam0" / "data.csv")) return "euroc";
  if (fs::exists(path / "times.txt") && fs::exists(path / "image_0")) return "kitti";
  for (const auto& entry : fs::directory_iterator(path)) {
    if (entry.is_regular_file() && IsImageFile(entry.path())) return "folder";
  }
  throw Error(path_text +
              ": not a dataset stitch knows: expected a TUM RGB-D folder (rgb.txt), EuRoC "
              "(mav0/cam0/data.csv), KITTI odometry (times.txt, image_0/), a folder of images or "
              "a video file");
}

std::unique_ptr<ImageSequence> OpenDataset(const std::string& path, const SequenceOptions& options) {
  const std::string kind = DetectDatasetKind(path);
  const fs::path root(path);
  if (kind == "tum") return OpenTum(root, options);
  if (kind == "euroc") return OpenEuroc(root, options);
  if (kind == "kitti") return OpenKitti(root, options);
  if (kind == "folder") return OpenImageFolder(root, options);
  return std::make_unique<VideoSequence>(root, options);
}

Trajectory ReadGroundTruth(const std::string& path, const std::string& kitti_times) {
  if (!fs::is_regular_file(path)) throw Error(path + ": no such ground-truth file");
  // The layout by the first data line: commas (EuRoC), 12 numbers (KITTI) or 8 (TUM).
  std::string first;
  ForEachDataLine(path, [&](const std::string& line, int) {
    if (first.empty()) first = line;
  });
  if (first.find(',') != std::string::npos) {
    const fs::path sensor = fs::path(path).parent_path().parent_path() / "cam0" / "sensor.yaml";
    if (!fs::exists(sensor)) {
      STITCH_LOG(WARNING) << path << ": EuRoC ground truth is the body's (IMU's) pose and no " << sensor.string()
                          << " gives the camera's place on it; evaluating against the body's poses";
    }
    return ReadEurocStateGroundTruth(path, fs::exists(sensor) ? ReadTBS(sensor.string()) : Eigen::Matrix4d::Identity());
  }
  std::istringstream fields(first);
  int count = 0;
  for (std::string field; fields >> field;) ++count;
  if (count == 12) {
    // KITTI poses carry no times: those of the sequence, times.txt (found beside the KITTI
    // layout's poses/NN.txt as sequences/NN/times.txt when not given).
    std::string times = kitti_times;
    if (times.empty()) {
      const fs::path guess =
          fs::path(path).parent_path().parent_path() / "sequences" / fs::path(path).stem() / "times.txt";
      if (!fs::exists(guess)) {
        throw Error(path + ": KITTI poses carry no times; give the sequence's times.txt (not found at " +
                    guess.string() + ")");
      }
      times = guess.string();
    }
    const std::vector<Rigid3d> poses = ReadKittiPoses(path);
    const std::vector<int64_t> t_ns = ReadKittiTimes(times);
    if (t_ns.size() != poses.size()) {
      throw Error(Str() << path << " holds " << poses.size() << " poses but " << times << " " << t_ns.size()
                        << " times; they must be of the same sequence");
    }
    std::vector<StampedPose> stamped;
    for (size_t i = 0; i < poses.size(); ++i) stamped.push_back({t_ns[i], poses[i]});
    return Trajectory(std::move(stamped));
  }
  if (count == 8) return Trajectory::ReadTum(path);
  throw Error(path +
              ": not a ground truth stitch reads (TUM: 'timestamp tx ty tz qx qy qz qw'; KITTI: 12 numbers a "
              "line; EuRoC: state_groundtruth_estimate0/data.csv)");
}

}  // namespace stitch
