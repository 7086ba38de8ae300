#include "stitch/source/source.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <tuple>

#include <opencv2/imgproc.hpp>

#include "stitch/config/ingest_options.h"
#include "stitch/geo/dji_srt.h"
#include "stitch/geo/exif_gps.h"
#include "stitch/geo/geoid.h"
#include "stitch/io/calibration.h"
#include "stitch/io/live_capture.h"
#include "stitch/io/video_decoder.h"

#include "stitch/util/error.h"
#include "stitch/util/options.h"

namespace stitch {
namespace {

// Plays only [start, start + max) of another sequence.
class ClippedSequence : public ImageSequence {
 public:
  ClippedSequence(std::unique_ptr<ImageSequence> inner, int start, int max_frames)
      : inner_(std::move(inner)), start_(start), max_frames_(max_frames) {
    const int total = inner_->size();
    size_ = total < 0 ? -1 : std::max(0, total - start_);
    if (max_frames_ >= 0 && (size_ < 0 || max_frames_ < size_)) size_ = max_frames_;
  }
  std::string description() const override { return inner_->description(); }
  int size() const override { return size_; }
  const Camera& camera() const override { return inner_->camera(); }
  double nominal_fps() const override { return inner_->nominal_fps(); }
  const Trajectory& ground_truth() const override { return inner_->ground_truth(); }
  bool Next(SequenceFrame* frame) override {
    while (skipped_ < start_) {
      if (!inner_->Next(frame)) return false;
      ++skipped_;
    }
    if (max_frames_ >= 0 && emitted_ >= max_frames_) return false;
    if (!inner_->Next(frame)) return false;
    frame->index = emitted_++;
    return true;
  }

 private:
  std::unique_ptr<ImageSequence> inner_;
  int start_, max_frames_, size_;
  int skipped_ = 0, emitted_ = 0;
};

// Frames reduced to the working size, with their camera: what the tracker, the mapper and the
// merger then see (docs/speed.md, "Working resolution").
class ReducedSequence : public ImageSequence {
 public:
  ReducedSequence(std::unique_ptr<ImageSequence> inner, const Camera& camera)
      : inner_(std::move(inner)), camera_(camera) {}
  std::string description() const override {
    return inner_->description() + ", reduced to " + std::to_string(camera_.width()) + "x" +
           std::to_string(camera_.height());
  }
  int size() const override { return inner_->size(); }
  const Camera& camera() const override { return camera_; }
  double nominal_fps() const override { return inner_->nominal_fps(); }
  const Trajectory& ground_truth() const override { return inner_->ground_truth(); }
  bool live() const override { return inner_->live(); }
  std::string image_path(int index) const override { return inner_->image_path(index); }
  int64_t dropped_at_source() const override { return inner_->dropped_at_source(); }
  bool Next(SequenceFrame* frame) override {
    if (!inner_->Next(frame)) return false;
    if (!frame->image.empty()) {
      frame->image = ReduceToWorkingSize(frame->image, cv::Size(camera_.width(), camera_.height()));
    }
    return true;
  }

 private:
  std::unique_ptr<ImageSequence> inner_;
  Camera camera_;
};

}  // namespace

int64_t SkipDeblockingFromPixels(const SourceSpec& spec) {
  if (!IsVideoDeblockingMode(spec.video_deblocking)) {
    throw Error("video deblocking is auto, on or off, not " + spec.video_deblocking);
  }
  if (spec.video_deblocking == "off") return 0;
  if (spec.video_deblocking == "on" || spec.max_working_pixels <= 0) return VideoDecoder::kNever;
  return 4 * static_cast<int64_t>(spec.max_working_pixels);  // halved at least once for the working size
}

std::pair<int, int> WorkingSize(int width, int height, int max_pixels) {
  if (max_pixels <= 0 || static_cast<int64_t>(width) * height <= max_pixels) return {width, height};
  const double factor = std::sqrt(static_cast<double>(max_pixels) / (static_cast<double>(width) * height));
  int w = std::max(1, static_cast<int>(std::floor(width * factor)));
  int h = std::max(1, static_cast<int>(std::lround(static_cast<double>(height) * w / width)));
  while (w > 1 && static_cast<int64_t>(w) * h > max_pixels) {
    --w;
    h = std::max(1, static_cast<int>(std::lround(static_cast<double>(height) * w / width)));
  }
  return {w, h};
}

cv::Mat ReduceToWorkingSize(const cv::Mat& image, const cv::Size& size) {
  // Exact halvings first, while the image stays at least the size (OpenCV's 2x2 block average),
  // then area averaging for what is left: a fractional reduction of a large frame is much
  // costlier, and of a halved one it costs a quarter.
  cv::Mat reduced = image;
  while (reduced.cols % 2 == 0 && reduced.rows % 2 == 0 && reduced.cols / 2 >= size.width &&
         reduced.rows / 2 >= size.height) {
    cv::Mat half;
    cv::resize(reduced, half, cv::Size(reduced.cols / 2, reduced.rows / 2), 0, 0, cv::INTER_AREA);
    reduced = half;
  }
  if (reduced.size() == size) return reduced;
  cv::Mat resized;
  cv::resize(reduced, resized, size, 0, 0, cv::INTER_AREA);
  return resized;
}

Camera WorkingCamera(const Camera& camera, int max_pixels) {
  const auto [width, height] = WorkingSize(camera.width(), camera.height(), max_pixels);
  return width == camera.width() && height == camera.height() ? camera : camera.Resized(width, height);
}

FailureSchedule ResolveFailures(const SourceSpec& spec, int num_frames) {
  if (spec.failures == "default") {
    return spec.synthetic_source() ? FailureSchedule::DefaultGusts(num_frames) : FailureSchedule();
  }
  return FailureSchedule::Parse(spec.failures);
}

std::unique_ptr<SyntheticSequence> OpenSyntheticFlight(const SourceSpec& spec) {
  const SyntheticOptions& options = spec.synthetic;
  const int played =
      spec.max_frames > 0 ? std::min(spec.max_frames, options.flight.num_frames) : options.flight.num_frames;
  // Gusts are scheduled in frames of the played part.
  const FailureSchedule gusts = ResolveFailures(spec, played);
  std::vector<FailureWindow> shifted;
  for (const auto& w : gusts.windows()) shifted.push_back({w.start + spec.start_frame, w.length});
  return std::make_unique<SyntheticSequence>(options, FailureSchedule(shifted));
}

namespace {

std::unique_ptr<ImageSequence> OpenAtFullSize(const SourceSpec& spec, FailureSchedule* spoil) {
  if (spec.synthetic_source()) {
    *spoil = FailureSchedule();
    std::unique_ptr<ImageSequence> sequence = OpenSyntheticFlight(spec);
    if (spec.start_frame == 0 && spec.max_frames < 0) return sequence;
    return std::make_unique<ClippedSequence>(std::move(sequence), spec.start_frame, spec.max_frames);
  }
  if (!spec.live_uri.empty()) {
    if (!spec.dataset_path.empty()) throw Error("give a live source or a dataset, not both");
    if (spec.start_frame > 0) throw Error("a live source has no frames to skip (--start-frame)");
    *spoil = ResolveFailures(spec, -1);
    LiveCaptureOptions options;
    options.calibration_path = spec.calibration_path;
    options.max_frames = spec.max_frames;
    options.clock = spec.live_clock;
    return std::make_unique<LiveCapture>(spec.live_uri, options);
  }
  SequenceOptions options;
  options.calibration_path = spec.calibration_path;
  options.start_frame = spec.start_frame;
  options.max_frames = spec.max_frames;
  options.video_skip_deblocking_from_pixels = SkipDeblockingFromPixels(spec);
  auto sequence = OpenDataset(spec.dataset_path, options);
  *spoil = ResolveFailures(spec, sequence->size());
  return sequence;
}

}  // namespace

std::unique_ptr<ImageSequence> OpenSource(const SourceSpec& spec, FailureSchedule* spoil) {
  auto sequence = OpenAtFullSize(spec, spoil);
  const Camera working = WorkingCamera(sequence->camera(), spec.max_working_pixels);
  if (working.width() == sequence->camera().width() && working.height() == sequence->camera().height()) {
    return sequence;
  }
  return std::make_unique<ReducedSequence>(std::move(sequence), working);
}

SourceSummary SummarizeSource(const SourceSpec& spec) {
  SourceSummary summary;
  if (spec.synthetic_source()) {
    const SyntheticOptions& options = spec.synthetic;
    CheckOptions(options, "synthetic");
    const int total = options.flight.num_frames;
    const int start = std::min(std::max(spec.start_frame, 0), total);
    const int played = spec.max_frames >= 0 ? std::min(spec.max_frames, total - start) : total - start;
    summary.failures = ResolveFailures(spec, played);
    std::vector<FailureWindow> shifted;
    for (const auto& w : summary.failures.windows()) shifted.push_back({w.start + start, w.length});
    const Camera camera = options.MakeCamera();
    summary.camera = WorkingCamera(camera, spec.max_working_pixels);
    const FlightPlan plan(options.flight, options.gust, camera, FailureSchedule(shifted),
                          static_cast<uint64_t>(options.seed));
    std::vector<StampedPose> poses;
    for (int i = start; i < start + played; ++i) poses.push_back({plan.TimestampNs(i), plan.WorldFromCam(i)});
    summary.ground_truth = Trajectory(std::move(poses));
    summary.num_frames = played;
    summary.fps = options.flight.fps;
    summary.gnss = SimulateGnssReceiver(summary.ground_truth, options.gnss, static_cast<uint64_t>(options.seed));
    summary.description = Str() << "synthetic UAV survey (seed " << options.seed << ", " << played << " frames, gusts "
                                << summary.failures.ToString() << ")";
    return summary;
  }
  if (!spec.live_uri.empty()) {
    LiveClock(spec.live_uri, spec.live_clock);  // throws for what is no live source, or a clock it has not
    if (spec.calibration_path.empty()) throw Error("a live camera needs its calibration (--calib FILE)");
    summary.camera = WorkingCamera(LoadCalibration(spec.calibration_path), spec.max_working_pixels);
    summary.description = "live " + spec.live_uri;
    summary.num_frames = spec.max_frames >= 0 ? spec.max_frames : -1;
    summary.failures = ResolveFailures(spec, -1);
    return summary;
  }
  FailureSchedule spoil;
  auto sequence = OpenSource(spec, &spoil);
  summary.description = sequence->description();
  summary.num_frames = sequence->size();
  summary.fps = sequence->nominal_fps();
  summary.camera = sequence->camera();
  summary.ground_truth = sequence->ground_truth();
  summary.failures = spoil;
  summary.gnss = DatasetGnss(spec.dataset_path);
  return summary;
}

GnssTrack SourceGnss(const SourceSpec& spec) {
  if (spec.synthetic_source()) return SummarizeSource(spec).gnss;
  return DatasetGnss(spec.dataset_path);
}

namespace {

// A track whose heights its source states above mean sea level (DJI's SRT, EXIF), raised to the
// ellipsoid; its source says where they could not be.
GnssTrack AboveTheEllipsoid(GnssTrack track) {
  if (const std::string why = HeightsAboveEllipsoid(&track.fixes); !why.empty()) {
    track.source += "; heights above mean sea level as stated, not the ellipsoid (" + why + ")";
  }
  return track;
}

// A folder of photos (DetectDatasetKind's "folder"): its images as played; empty for anything
// else. Throws what FolderImageTimes throws.
std::vector<ImageEntry> PhotoFolderImages(const std::string& path) {
  if (!std::filesystem::is_directory(path)) return {};
  std::string kind;
  try {
    kind = DetectDatasetKind(path);
  } catch (const Error&) {
    return {};
  }
  return kind == "folder" ? FolderImageTimes(path) : std::vector<ImageEntry>();
}

}  // namespace

GnssTrack DatasetGnss(const std::string& dataset_path) {
  namespace fs = std::filesystem;
  if (dataset_path.empty()) return {};
  if (const std::string gnss = GnssFileBeside(dataset_path); fs::is_regular_file(gnss)) return ReadGnssCsv(gnss);
  if (fs::is_directory(dataset_path)) {
    // A folder of photos: the EXIF GPS tags a survey camera wrote into each.
    const std::vector<ImageEntry> photos = PhotoFolderImages(dataset_path);
    return photos.empty() ? GnssTrack() : AboveTheEllipsoid(ExifGnssTrack(photos));
  }
  for (const char* extension : {".SRT", ".srt"}) {
    const fs::path srt = fs::path(dataset_path).replace_extension(extension);
    if (fs::is_regular_file(srt)) return AboveTheEllipsoid(ReadDjiSrt(srt.string()));
  }
  return {};
}

std::string GnssFileBeside(const std::string& dataset_path) {
  namespace fs = std::filesystem;
  if (dataset_path.empty()) return "";
  if (fs::is_directory(dataset_path)) return (fs::path(dataset_path) / "gnss.csv").string();
  return fs::path(dataset_path).replace_extension(".gnss.csv").string();
}

void AddSourceOptions(ArgParser* args, SourceSpec* spec, unsigned which) {
  if (which & kDatasetFlag) {
    args->AddOption("--dataset", &spec->dataset_path, "PATH",
                    "a TUM RGB-D, EuRoC or KITTI folder, an image folder or a video (detected; default: the synthetic "
                    "UAV survey flight)");
  }
  if (which & kLiveFlag) {
    args->AddOption("--live", &spec->live_uri, "URI",
                    "a live camera instead: a V4L2 device (/dev/video0), a GStreamer pipeline ('... ! appsink') or a "
                    "stream URL (rtsp://, udp://); needs --calib; runs until the stream ends, --max-frames or Ctrl-C");
    args->AddOption("--live-clock", &spec->live_clock, "CLOCK",
                    "the live frames' times: wall (the wall clock at capture), stream (a GStreamer pipeline's own: a "
                    "recorded clip keeps its times and its ground truth) or auto (stream for a pipeline that reads a "
                    "file, wall otherwise)");
  }
  if (which & kCalibFlag) {
    args->AddOption("--calib", &spec->calibration_path, "FILE",
                    "calibration overriding the dataset's own (required with --live); an ORB-SLAM2/3 settings file's "
                    "ORBextractor.* also set tracker.tracking.orb (under --set) where the program tracks");
  }
  if (which & kFailuresFlag) {
    args->AddOption("--failures", &spec->failures, "SPEC",
                    "induced failures: none, FRAME:LENGTH,... or default (the synthetic flight: 3 gusts; datasets: "
                    "none)");
  }
  if (which & kMaxFramesFlag)
    args->AddOption("--max-frames", &spec->max_frames, "N", "play at most N frames (-1: all)");
  if (which & kStartFrameFlag) {
    args->AddOption("--start-frame", &spec->start_frame, "N", "skip the first N frames of the sequence");
  }
}

void CheckSourceSpec(const SourceSpec& spec) {
  if (spec.start_frame < 0) throw Error("--start-frame must be >= 0");
}

std::vector<std::string> SourceArguments(const SourceSpec& spec, unsigned which) {
  const SourceSpec defaults;
  const std::tuple<SourceFlag, const char*, std::string, std::string> flags[] = {
      {kDatasetFlag, "--dataset", spec.dataset_path, defaults.dataset_path},
      {kLiveFlag, "--live", spec.live_uri, defaults.live_uri},
      {kLiveFlag, "--live-clock", spec.live_clock, defaults.live_clock},
      {kCalibFlag, "--calib", spec.calibration_path, defaults.calibration_path},
      {kFailuresFlag, "--failures", spec.failures, defaults.failures},
      {kMaxFramesFlag, "--max-frames", std::to_string(spec.max_frames), std::to_string(defaults.max_frames)},
      {kStartFrameFlag, "--start-frame", std::to_string(spec.start_frame), std::to_string(defaults.start_frame)}};
  std::vector<std::string> args;
  for (const auto& [flag, name, value, default_value] : flags) {
    if (!(which & flag) || value == default_value) continue;
    args.push_back(name);
    args.push_back(value);
  }
  return args;
}

std::string SourceCameraUpAxis(const SourceSpec& spec) {
  if (spec.synthetic_source()) return spec.synthetic.flight.camera_pitch_deg == 0.0 ? "-z" : "";
  if (!spec.live_uri.empty()) return "";
  // A drone's photos: the gimbal's pitch in their XMP.
  try {
    return PhotosStateANadirGimbal(PhotoFolderImages(spec.dataset_path)) ? "-z" : "";
  } catch (const Error&) {
    return "";
  }
}

double SourceLineDelayUs(const SourceSpec& spec, const Camera& working) {
  if (spec.synthetic_source()) {
    return spec.synthetic.camera.rolling_shutter_line_us * spec.synthetic.height / working.height();
  }
  const std::filesystem::path data(spec.dataset_path);
  std::vector<std::filesystem::path> candidates;
  if (!spec.calibration_path.empty()) candidates.push_back(spec.calibration_path);
  if (!spec.dataset_path.empty()) {
    candidates.insert(candidates.end(),
                      {data / "camera.yaml", data / "calibration.yaml",
                       std::filesystem::path(data).replace_extension(".yaml"), data.parent_path() / "camera.yaml"});
  }
  for (const std::filesystem::path& candidate : candidates) {
    std::error_code error;
    if (!std::filesystem::is_regular_file(candidate, error)) continue;
    if (const auto line_delay_us = ReadLineDelayUs(candidate.string())) {
      int rows = working.height();  // a calibration that states no image size is the frames'
      try {
        rows = LoadCalibration(candidate.string()).height();
      } catch (const Error&) {
      }
      return *line_delay_us * rows / working.height();
    }
  }
  return 0;
}

}  // namespace stitch
