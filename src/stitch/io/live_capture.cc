#include "stitch/io/live_capture.h"

#include <chrono>

#include <opencv2/imgproc.hpp>

#include "stitch/io/calibration.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"

namespace stitch {
namespace {

bool StartsWith(const std::string& text, const std::string& prefix) {
  return text.rfind(prefix, 0) == 0;
}

int64_t WallClockNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
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

LiveCapture::LiveCapture(const std::string& uri, const LiveCaptureOptions& options)
    : uri_(uri), kind_(LiveSourceKind(uri)), options_(options) {
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
  if (fps > 0 && fps < 1000) fps_ = fps;
  // The first frame, here: the image size to check the calibration against.
  cv::Mat first;
  if (!capture.read(first) || first.empty()) throw Error("live source " + uri_ + ": it gave no frame");
  shared_->latest_t_ns = WallClockNs();
  shared_->latest = ToGray(first);
  camera_ = LoadCalibration(options_.calibration_path, shared_->latest.cols, shared_->latest.rows);
  thread_ = std::thread(&LiveCapture::Capture, shared_);
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
         std::to_string(camera_.height()) + ", " + std::to_string(static_cast<int>(fps_ + 0.5)) + " fps)";
}

void LiveCapture::Capture(std::shared_ptr<Shared> shared) {
  cv::Mat image;
  while (!shared->stop.load()) {
    if (!shared->capture.read(image) || image.empty()) break;
    const int64_t t_ns = WallClockNs();
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
