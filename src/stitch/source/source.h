#pragma once
// Opens what a run plays: a dataset on disk (detected kind) or the synthetic flight.

#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "stitch/geo/gnss_fix.h"
#include "stitch/io/failure_schedule.h"
#include "stitch/io/image_sequence.h"
#include "stitch/synthetic/synthetic_sequence.h"
#include "stitch/util/args.h"

namespace stitch {

struct SourceSpec {
  std::string live_uri;              // a live camera (LiveCapture): a V4L2 device, GStreamer pipeline or stream URL
  std::string live_clock = "auto";   // its frames' times: auto, stream or wall (LiveCaptureOptions::clock)
  std::string dataset_path;          // empty (and no live_uri): the synthetic flight
  std::string calibration_path;      // overrides the dataset's calibration
  std::string failures = "default";  // "default" (synthetic: 3 gusts; datasets: none), "none", or FRAME:LENGTH,...
  int max_frames = -1;               // -1: all
  int start_frame = 0;
  // Frames of more pixels than this are reduced to the working size (WorkingSize), with their
  // camera; 0: frames as they come (ingest.max_working_pixels sets it for a run).
  int max_working_pixels = 0;
  std::string video_deblocking = "auto";  // a video file's deblocking filter: auto, on, off (ingest.video_deblocking)
  SyntheticOptions synthetic;             // used when dataset_path is empty

  bool synthetic_source() const { return dataset_path.empty() && live_uri.empty(); }
};

// The flags that choose what a program plays, declared once for every program that takes them
// (stitch run, stitch bench, stitch render, stitch-ingest): `which` says which of them.
enum SourceFlag : unsigned {
  kDatasetFlag = 1u << 0,     // --dataset PATH
  kLiveFlag = 1u << 1,        // --live URI, --live-clock CLOCK
  kCalibFlag = 1u << 2,       // --calib FILE
  kFailuresFlag = 1u << 3,    // --failures SPEC
  kMaxFramesFlag = 1u << 4,   // --max-frames N
  kStartFrameFlag = 1u << 5,  // --start-frame N
  kEverySourceFlag = (1u << 6) - 1,
};
void AddSourceOptions(ArgParser* args, SourceSpec* spec, unsigned which = kEverySourceFlag);
// Throws stitch::Error for values no source takes (a negative start frame).
void CheckSourceSpec(const SourceSpec& spec);
// The flags among `which` that hand `spec` on to another program taking them (those set away
// from SourceSpec's defaults), e.g. {"--dataset", PATH, "--max-frames", "300"}.
std::vector<std::string> SourceArguments(const SourceSpec& spec, unsigned which = kEverySourceFlag);

// The working size of frames of `width` x `height`: the size itself when it has at most
// `max_pixels` pixels (or `max_pixels` is 0), else the largest size within it whose aspect is the
// frame's to the pixel.
std::pair<int, int> WorkingSize(int width, int height, int max_pixels);
// The frames of a video of at least this many pixels are decoded without the deblocking filter, by
// spec.video_deblocking: auto: those halved at least once for their working size (4 x
// max_working_pixels: 1080p and 4K by default); on: none; off: all.
int64_t SkipDeblockingFromPixels(const SourceSpec& spec);
// `camera` for frames at their working size.
Camera WorkingCamera(const Camera& camera, int max_pixels);
// `image` reduced to `size` by area averaging, as a source with a working size sends it: halved
// exactly (2x2 block averages) while it stays at least `size`, then averaged to `size` (1080p and
// 4K within 500,000 pixels: halved to 960x540, then to 942x530): a fraction of the cost of one
// fractional reduction from the full frame (features_benchmark's BM_ReduceToWorkingSize).
cv::Mat ReduceToWorkingSize(const cv::Mat& image, const cv::Size& size);

// The failure schedule the spec means for a sequence of `num_frames` frames.
FailureSchedule ResolveFailures(const SourceSpec& spec, int num_frames);

// Opens the source. For the synthetic flight the failure schedule becomes gusts (rendered into the
// sequence); for datasets it is returned in `spoil` for ingest to apply. Throws stitch::Error.
std::unique_ptr<ImageSequence> OpenSource(const SourceSpec& spec, FailureSchedule* spoil);

// The whole synthetic flight `spec` plays (spec.synthetic, its gusts shifted by the start frame),
// from its first frame: what OpenSource clips to the played part. Throws stitch::Error.
std::unique_ptr<SyntheticSequence> OpenSyntheticFlight(const SourceSpec& spec);

// Ground truth and length without rendering or reading images where avoidable (the launcher
// needs them; ingest does the playing). A live source is not opened here (a device may be
// opened once only): its camera comes from the calibration file, its length is unknown (-1).
struct SourceSummary {
  std::string description;
  int num_frames = -1;
  double fps = 0;
  Camera camera;
  Trajectory ground_truth;
  FailureSchedule failures;
  // The aircraft's GNSS fixes: the synthetic receiver's, or a dataset's (DatasetGnss); no fixes
  // where there are none.
  GnssTrack gnss;
};
SourceSummary SummarizeSource(const SourceSpec& spec);

// The GNSS fixes of what `spec` plays: the synthetic receiver's over the frames played
// (SummarizeSource's), a dataset's (DatasetGnss); none for a live camera. Throws stitch::Error for a
// malformed gnss.csv.
GnssTrack SourceGnss(const SourceSpec& spec);
// Where a dataset's GNSS fixes are: DIR/gnss.csv for a folder, FILE.gnss.csv beside a video
// FILE.mp4 (what `stitch render` writes).
std::string GnssFileBeside(const std::string& dataset_path);
// A dataset's fixes: its gnss.csv (GnssFileBeside), else the DJI track beside a video
// (FILE.SRT, ReadDjiSrt), else, for an image folder, its photos' EXIF GPS tags (ExifGnssTrack,
// each at its photo's time); none where it has none of them. Throws stitch::Error for a malformed
// gnss.csv or .SRT.
GnssTrack DatasetGnss(const std::string& dataset_path);

// The rolling shutter's readout delay per row of the frames the tracker sees (`working`: frames
// reduced to a working size take as long per row as the source's rows they hold) as the source
// states it: the synthetic flight's camera, else Camera.line_delay_us in the calibration found
// beside the data (as `stitch render` writes it); 0 when none says. What
// tracker.tracking.rolling_shutter_line_us -1 resolves to.
double SourceLineDelayUs(const SourceSpec& spec, const Camera& working);

// The camera's axis that points up, where the source states how its camera is mounted: "-z" for
// the synthetic flight's gimballed camera looking straight down (synthetic.flight.camera_pitch_deg
// 0), and for a folder of a drone's photos whose XMP says its gimbal looked straight down
// (PhotosStateANadirGimbal); "" where the source says nothing (videos, other datasets, live
// cameras, a tilted camera). What merger.georeference.level_by_camera auto resolves by.
std::string SourceCameraUpAxis(const SourceSpec& spec);

}  // namespace stitch
