#pragma once
// Writes gray frames as an H.264 video file through GStreamer's x264 encoder (Debian:
// gstreamer1.0-plugins-ugly), in MP4, Matroska or QuickTime by the file's extension: the kind of
// file an aircraft's camera records. `stitch render --out flight.mp4` writes one; `stitch run
// --dataset flight.mp4` and `--live 'filesrc location=flight.mp4 ! decodebin ! appsink'` play it.
// Frame i is stamped i / fps in the clip.

#include <string>

#include <opencv2/core.hpp>
#include <opencv2/videoio.hpp>

namespace stitch {

struct H264FileOptions {
  double fps = 30.0;
  int quantizer = 18;  // x264's constant quality (0 lossless .. 50); 18 keeps the corners a tracker needs
  // The stream's most bits per second, kbit/s: an aircraft camera's recording rate (a DJI Phantom 4
  // records 4K at 100 Mbit/s, 1080p at 60). x264enc's own default (2048) capped every clip at
  // 2 Mbit/s whatever the quantizer, a 4K frame at 8 kB: blocks where the ground's texture was.
  int max_bitrate_kbps = 100000;
  std::string speed_preset = "faster";  // x264's speed preset
};

class H264FileWriter {
 public:
  // Opens `path` (.mp4, .mkv or .mov) for frames of `width` x `height`. The file is written beside
  // it as PATH.part and takes its name when finished, so a file under `path` is always whole.
  // Throws stitch::Error for another extension, a path GStreamer cannot name, or a missing encoder.
  H264FileWriter(const std::string& path, int width, int height, const H264FileOptions& options = {});
  ~H264FileWriter();  // finishes the file, when Finish() was not called
  H264FileWriter(const H264FileWriter&) = delete;
  H264FileWriter& operator=(const H264FileWriter&) = delete;

  // Throws stitch::Error for a frame of another size, or not 8-bit gray.
  void Write(const cv::Mat& gray);
  // Ends the stream (the container's index is written then) and gives the file its name. Throws
  // stitch::Error when nothing whole came out.
  void Finish();
  int frames_written() const { return frames_; }

 private:
  std::string path_, part_;
  int width_, height_;
  int frames_ = 0;
  bool finished_ = false;
  cv::VideoWriter writer_;
  cv::Mat bgr_;  // the frame as the encoder takes it
};

}  // namespace stitch
