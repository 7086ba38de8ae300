#pragma once
// Decodes a video file's frames as 8-bit grey images with their presentation times, through
// FFmpeg's libavformat and libavcodec (Debian's, the ones OpenCV's own video reader uses).
//
// Why not cv::VideoCapture: it converts every decoded frame to BGR (and we then to grey), two
// full-size passes that cost more than a third of a 1080p H.264 frame's decoding; the grey image
// is the decoded frame's luma plane, taken here as it comes (stretched to full range where the
// clip is in video range: 16-235 becomes 0-255, the grey that BGR's conversion gave).

#include <cstdint>
#include <limits>
#include <memory>
#include <string>

#include <opencv2/core.hpp>

namespace stitch {

class VideoDecoder {
 public:
  // Opens `path` and its best video stream. Frames of at least `skip_deblocking_from_pixels`
  // pixels are decoded without the codec's deblocking (loop) filter, about a fifth of an H.264
  // frame's decoding (default: never). Throws stitch::Error for a file that is not a video FFmpeg
  // can read, a codec it lacks, or frames of an implausible size.
  explicit VideoDecoder(const std::string& path, int64_t skip_deblocking_from_pixels = kNever);
  static constexpr int64_t kNever = std::numeric_limits<int64_t>::max();
  ~VideoDecoder();
  VideoDecoder(const VideoDecoder&) = delete;
  VideoDecoder& operator=(const VideoDecoder&) = delete;

  // The next frame: a grey image of its own (8-bit, the stream's size) and its presentation time
  // in the clip, nanoseconds from the stream's start (-1 where the stream gives none). False at
  // the end of the stream. A packet the decoder refuses (a damaged clip) is skipped and counted,
  // and so is a frame of another size than the stream's first.
  bool Read(cv::Mat* gray, int64_t* time_ns);
  // Decodes the next frame without converting it (skipping the start of a clip). False at the end.
  bool Skip();

  int width() const { return width_; }
  int height() const { return height_; }
  double fps() const { return fps_; }             // the stream's frame rate (0 where it states none)
  int64_t frame_count() const { return count_; }  // frames the container lists (-1 where it does not)
  int skipped_packets() const { return skipped_packets_; }
  int skipped_frames() const { return skipped_frames_; }
  bool deblocking() const { return deblocking_; }

 private:
  struct Libav;  // FFmpeg's contexts (kept out of this header)
  bool NextFrame();
  void ToGray(cv::Mat* gray);

  std::unique_ptr<Libav> av_;
  std::string path_;
  int width_ = 0, height_ = 0;
  double fps_ = 0;
  int64_t count_ = -1;
  int skipped_packets_ = 0, skipped_frames_ = 0;
  bool deblocking_ = true;
  bool flushing_ = false, ended_ = false;
};

}  // namespace stitch
