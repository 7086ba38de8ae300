#include "stitch/io/live_capture.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include <opencv2/imgproc.hpp>

#include "stitch/io/calibration.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "stitch/util/time.h"

namespace stitch {
namespace {

bool StartsWith(const std::string& text, const std::string& prefix) {
  return text.rfind(prefix, 0) == 0;
}

// The frame as 8-bit gray (what the tracker takes).
cv::Mat ToGray(const cv::Mat& image) {
  cv::Mat gray;
  if (image.channels() == 3) {
    cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
  } else if (image.channels() == 4) {
    cv::cvtColor(image, gray, cv::COLOR_BGRA2GRAY);
  } else {
    gray = image.clone();
  }
  if (gray.depth() != CV_8U) gray.convertTo(gray, CV_8U, gray.depth() == CV_16U ? 1.0 / 256 : 1.0);
  return gray;
}

}  // namespace

std::string LiveSourceKind(const std::string& uri) {
  if (StartsWith(uri, "v4l2:") || StartsWith(uri, "/dev/video")) return "v4l2";
  if (StartsWith(uri, "gst:") || uri.find(" ! ") != std::string::npos) return "gstreamer";
  for (const char* scheme : {"rtsp://", "rtsps://", "udp://", "rtp://", "tcp://", "http://", "https://"}) {
    if (StartsWith(uri, scheme)) return "stream";
  }
  throw Error("live source '" + uri +
              "': expected a V4L2 device (/dev/video0), a GStreamer pipeline (elements joined by ' ! ', or gst:...) "
              "or a stream URL (rtsp://, udp://, http://)");
}

std::string LiveClock(const std::string& uri, const std::string& clock) {
  const std::string kind = LiveSourceKind(uri);
  if (clock == "wall") return clock;
  if (clock == "stream") {
    if (kind != "gstreamer") throw Error("live source " + uri + ": only a GStreamer pipeline gives its own clock");
    return clock;
  }
  if (clock != "auto") throw Error("live clock '" + clock + "': expected auto, stream or wall");
  if (kind != "gstreamer") return "wall";
  // The pipeline's source element: the first one.
  const std::string pipeline = StartsWith(uri, "gst:") ? uri.substr(4) : uri;
  const size_t begin = pipeline.find_first_not_of(' ');
  const std::string first =
      begin == std::string::npos ? "" : pipeline.substr(begin, pipeline.find_first_of(" !", begin) - begin);
  const bool reads_file = first == "filesrc" || first == "multifilesrc" ||
                          (first == "uridecodebin" && pipeline.find("uri=file:") != std::string::npos);
  return reads_file ? "stream" : "wall";
}

LiveCapture::LiveCapture(const std::string& uri, const LiveCaptureOptions& options)
    : uri_(uri), kind_(LiveSourceKind(uri)), clock_(LiveClock(uri, options.clock)), options_(options) {
  if (options_.calibration_path.empty()) {
    throw Error("live source " + uri_ + ": a live camera needs its calibration (--calib FILE)");
  }
  if (!(options_.frame_timeout_s > 0)) throw Error("live source: frame_timeout_s must be > 0");
  cv::VideoCapture& capture = shared_->capture;
  bool opened = false;
  if (kind_ == "v4l2") {
    opened = capture.open(StartsWith(uri_, "v4l2:") ? uri_.substr(5) : uri_, cv::CAP_V4L2);
  } else if (kind_ == "gstreamer") {
    std::string pipeline = StartsWith(uri_, "gst:") ? uri_.substr(4) : uri_;
    // OpenCV takes frames from an appsink at the pipeline's end.
    if (pipeline.find("appsink") == std::string::npos) pipeline += " ! videoconvert ! appsink";
    opened = capture.open(pipeline, cv::CAP_GSTREAMER);
  } else {
    opened = capture.open(uri_, cv::CAP_ANY);
  }
  if (!opened || !capture.isOpened()) {
    throw Error("live source " + uri_ + " (" + kind_ +
                "): cannot open it (a missing device or GStreamer plugin, a wrong pipeline, an unreachable stream)");
  }
  const double fps = capture.get(cv::CAP_PROP_FPS);
  if (fps > 0 && fps < 1000) fps_ = shared_->fps = fps;
  // The first frame, here: the image size to check the calibration against.
  cv::Mat first;
  if (!capture.read(first) || first.empty()) throw Error("live source " + uri_ + ": it gave no frame");
  shared_->latest_t_ns = CaptureTimeNs(shared_.get(), clock_ == "stream");
  shared_->latest = ToGray(first);
  camera_ = LoadCalibration(options_.calibration_path, shared_->latest.cols, shared_->latest.rows);
  thread_ = std::thread(&LiveCapture::Capture, shared_, clock_ == "stream");
}

LiveCapture::~LiveCapture() {
  shared_->stop = true;
  // The capture thread notices between two frames (a read returns at the camera's next frame);
  // one that a stalled stream holds in its read is left to finish on its own.
  std::unique_lock<std::mutex> lock(shared_->mutex);
  const bool ended = shared_->changed.wait_for(lock, std::chrono::seconds(2), [&] { return shared_->ended; });
  lock.unlock();
  if (ended) {
    thread_.join();
  } else {
    STITCH_LOG(WARNING) << "live source " << uri_ << ": the capture is stuck in a read; leaving it behind";
    thread_.detach();
  }
}

std::string LiveCapture::description() const {
  return "live " + kind_ + " " + uri_ + " (" + std::to_string(camera_.width()) + "x" +
         std::to_string(camera_.height()) + ", " + std::to_string(static_cast<int>(fps_ + 0.5)) + " fps, " + clock_ +
         " clock)";
}

int64_t LiveCapture::CaptureTimeNs(Shared* shared, bool stream_clock) {
  int64_t t_ns = WallClockNs();
  if (stream_clock) {
    // OpenCV answers with the pipeline's position when asked: the frame's time in the stream plus
    // however late this thread took it (a few milliseconds, more on a loaded machine). On a
    // stream of a known rate that is the frame period's multiple nearest to it.
    const double position_ms = shared->capture.get(cv::CAP_PROP_POS_MSEC);
    if (std::isfinite(position_ms) && position_ms >= 0) {
      t_ns = static_cast<int64_t>(std::llround(position_ms * 1e6));
      if (shared->fps > 0) {
        const double period_ns = 1e9 / shared->fps;
        t_ns = static_cast<int64_t>(std::llround(std::round(t_ns / period_ns) * period_ns));
      }
    } else {
      t_ns = shared->last_t_ns + 1;
    }
  }
  // Times strictly in order, whatever the clock did.
  t_ns = std::max(t_ns, shared->last_t_ns + 1);
  shared->last_t_ns = t_ns;
  return t_ns;
}

void LiveCapture::Capture(std::shared_ptr<Shared> shared, bool stream_clock) {
  cv::Mat image;
  while (!shared->stop.load()) {
    if (!shared->capture.read(image) || image.empty()) break;
    const int64_t t_ns = CaptureTimeNs(shared.get(), stream_clock);
    cv::Mat gray = ToGray(image);
    std::lock_guard<std::mutex> lock(shared->mutex);
    if (!shared->latest.empty()) ++shared->dropped;  // the consumer did not take the last one in time
    shared->latest = std::move(gray);
    shared->latest_t_ns = t_ns;
    shared->changed.notify_all();
  }
  std::lock_guard<std::mutex> lock(shared->mutex);
  shared->ended = true;
  shared->changed.notify_all();
}

bool LiveCapture::Next(SequenceFrame* frame) {
  if (options_.max_frames >= 0 && emitted_ >= options_.max_frames) return false;
  std::unique_lock<std::mutex> lock(shared_->mutex);
  const bool ready = shared_->changed.wait_for(lock, std::chrono::duration<double>(options_.frame_timeout_s),
                                               [&] { return !shared_->latest.empty() || shared_->ended; });
  if (shared_->latest.empty()) {
    if (!ready) {
      STITCH_LOG(WARNING) << "live source " << uri_ << ": no frame for " << options_.frame_timeout_s
                          << " s; taking the stream as ended";
    }
    return false;
  }
  frame->index = emitted_++;
  frame->t_ns = shared_->latest_t_ns;
  frame->image = std::move(shared_->latest);
  frame->error.clear();
  shared_->latest = cv::Mat();
  return true;
}

}  // namespace stitch
