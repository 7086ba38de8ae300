#pragma once
// A live camera as an ImageSequence: a V4L2 device, a GStreamer pipeline or a network stream
// (RTSP, UDP, HTTP) read through OpenCV's VideoCapture by a capture thread of its own. Each frame
// is stamped with the wall clock when it was captured, or with the stream's own time where that
// is what counts (a recorded clip played through a pipeline: its frames keep the clip's times, so
// its ground truth still applies); only the newest frame is kept, so a
// consumer that falls behind gets the latest one and the frames it missed are counted
// (dropped_at_source()), never queued. The calibration file is required: a live source has none
// of its own.

#include <atomic>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include <opencv2/videoio.hpp>

#include "stitch/io/image_sequence.h"

namespace stitch {

struct LiveCaptureOptions {
  std::string calibration_path;   // required
  int max_frames = -1;            // stop after this many frames (-1: until the stream ends)
  double frame_timeout_s = 10.0;  // no frame for this long: the stream is taken as ended
  // The frames' times: "wall" (the wall clock at capture), "stream" (the pipeline's own position,
  // on the grid of its nominal frame rate when it has one: a GStreamer pipeline only), or "auto"
  // (stream for a pipeline that reads a file: filesrc, multifilesrc, uridecodebin of a file:
  // URI; wall otherwise).
  std::string clock = "auto";
};

// The clock `options.clock` means for `uri` ("wall" or "stream"). Throws stitch::Error for an
// unknown clock, or "stream" for a source that is not a GStreamer pipeline.
std::string LiveClock(const std::string& uri, const std::string& clock);

// How VideoCapture is to open `uri`: "v4l2" (/dev/videoN, or "v4l2:/dev/videoN"), "gstreamer"
// (a pipeline: elements joined by " ! "; "gst:PIPELINE" too), "stream" (rtsp://, udp://,
// http(s)://, tcp://). Throws stitch::Error for anything else.
std::string LiveSourceKind(const std::string& uri);

class LiveCapture : public ImageSequence {
 public:
  // Opens the source and waits for its first frame (at most options.frame_timeout_s). Throws
  // stitch::Error when it cannot be opened, gives no frame, or the calibration does not fit it.
  LiveCapture(const std::string& uri, const LiveCaptureOptions& options);
  ~LiveCapture() override;
  LiveCapture(const LiveCapture&) = delete;
  LiveCapture& operator=(const LiveCapture&) = delete;

  std::string description() const override;
  int size() const override { return -1; }
  const Camera& camera() const override { return camera_; }
  double nominal_fps() const override { return fps_; }
  const Trajectory& ground_truth() const override { return ground_truth_; }
  bool live() const override { return true; }
  // The newest frame not yet returned, waiting for one if need be; false when the stream ended
  // (or gave nothing for options.frame_timeout_s), or after max_frames.
  bool Next(SequenceFrame* frame) override;
  // Frames captured but replaced by a newer one before Next() took them.
  int64_t dropped_at_source() const override { return shared_->dropped.load(); }

 private:
  // What the capture thread shares with the reader. Held by both: a thread blocked in a stalled
  // stream's read is left to end on its own (detached) rather than hang the destructor.
  struct Shared {
    cv::VideoCapture capture;
    std::mutex mutex;
    std::condition_variable changed;
    cv::Mat latest;  // newest captured frame, gray; empty once taken
    int64_t latest_t_ns = 0;
    bool ended = false;
    std::atomic<bool> stop{false};
    std::atomic<int64_t> dropped{0};
    double fps = 0;          // the stream's nominal rate (0: unknown)
    int64_t last_t_ns = -1;  // the capture thread's own: the last frame's time
  };
  static void Capture(std::shared_ptr<Shared> shared, bool stream_clock);
  // The capture time of the frame `capture` just read.
  static int64_t CaptureTimeNs(Shared* shared, bool stream_clock);

  std::string uri_, kind_, clock_;
  LiveCaptureOptions options_;
  std::shared_ptr<Shared> shared_ = std::make_shared<Shared>();
  Camera camera_;
  Trajectory ground_truth_;
  double fps_ = 30.0;
  int emitted_ = 0;
  std::thread thread_;
};

}  // namespace stitch
