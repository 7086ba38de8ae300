#include "stitch/io/live_capture.h"

#include <chrono>

#include <opencv2/imgproc.hpp>

#include "stitch/io/calibration.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"

namespace stitch {
namespace {

bool StartsWith(const std::string& text, const std::string& prefix) { return text.rfind(prefix, 0) == 0; }

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
  bool opened = false;
  if (kind_ == "v4l2") {
    opened = capture_.open(StartsWith(uri_, "v4l2:") ? uri_.substr(5) : uri_, cv::CAP_V4L2);
  } else if (kind_ == "gstreamer") {
    std::string pipeline = StartsWith(uri_, "gst:") ? uri_.substr(4) : uri_;
    // OpenCV takes frames from an appsink at the pipeline's end.
    if (pipeline.find("appsink") == std::string::npos) pipeline += " ! videoconvert ! appsink";
    opened = capture_.open(pipeline, cv::CAP_GSTREAMER);
  } else {
    opened = capture_.open(uri_, cv::CAP_ANY);
  }
  if (!opened || !capture_.isOpened()) {
    throw Error("live source " + uri_ + " (" + kind_ +
                "): cannot open it (a missing device or GStreamer plugin, a wrong pipeline, an unreachable stream)");
  }
  const double fps = capture_.get(cv::CAP_PROP_FPS);
  if (fps > 0 && fps < 1000) fps_ = fps;
  // The first frame, here: the image size to check the calibration against.
  cv::Mat first;
  if (!capture_.read(first) || first.empty()) throw Error("live source " + uri_ + ": it gave no frame");
  latest_t_ns_ = WallClockNs();
  latest_ = ToGray(first);
  camera_ = LoadCalibration(options_.calibration_path, latest_.cols, latest_.rows);
  thread_ = std::thread([this] { Capture(); });
}

LiveCapture::~LiveCapture() {
  stop_ = true;
  // The capture thread notices between two frames (a read returns at the camera's next frame).
  if (thread_.joinable()) thread_.join();
}

std::string LiveCapture::description() const {
  return "live " + kind_ + " " + uri_ + " (" + std::to_string(camera_.width()) + "x" +
         std::to_string(camera_.height()) + ", " + std::to_string(static_cast<int>(fps_ + 0.5)) + " fps)";
}

void LiveCapture::Capture() {
  cv::Mat image;
  while (!stop_.load()) {
    if (!capture_.read(image) || image.empty()) break;
    const int64_t t_ns = WallClockNs();
    cv::Mat gray = ToGray(image);
    std::lock_guard<std::mutex> lock(mutex_);
    if (!latest_.empty()) ++dropped_;  // the consumer did not take the last one in time
    latest_ = std::move(gray);
    latest_t_ns_ = t_ns;
    changed_.notify_all();
  }
  std::lock_guard<std::mutex> lock(mutex_);
  ended_ = true;
  changed_.notify_all();
}

bool LiveCapture::Next(SequenceFrame* frame) {
  if (options_.max_frames >= 0 && emitted_ >= options_.max_frames) return false;
  std::unique_lock<std::mutex> lock(mutex_);
  const bool ready = changed_.wait_for(lock, std::chrono::duration<double>(options_.frame_timeout_s),
                                       [&] { return !latest_.empty() || ended_; });
  if (latest_.empty()) {
    if (!ready) {
      STITCH_LOG(WARNING) << "live source " << uri_ << ": no frame for " << options_.frame_timeout_s
                          << " s; taking the stream as ended";
    }
    return false;
  }
  frame->index = emitted_++;
  frame->t_ns = latest_t_ns_;
  frame->image = std::move(latest_);
  frame->error.clear();
  latest_ = cv::Mat();
  return true;
}

}  // namespace stitch
