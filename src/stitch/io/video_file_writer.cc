#include "stitch/io/video_file_writer.h"

#include <filesystem>
#include <system_error>

#include <opencv2/imgproc.hpp>

#include "stitch/util/error.h"
#include "stitch/util/log.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

// GStreamer's muxer for a file of this extension.
std::string MuxerFor(const fs::path& path) {
  const std::string ext = path.extension().string();
  if (ext == ".mp4" || ext == ".m4v") return "mp4mux";
  if (ext == ".mkv") return "matroskamux";
  if (ext == ".mov") return "qtmux";
  throw Error(path.string() + ": an H.264 video is written as .mp4, .mkv or .mov");
}

}  // namespace

H264FileWriter::H264FileWriter(const std::string& path, int width, int height, const H264FileOptions& options)
    : path_(path), part_(path + ".part"), width_(width), height_(height) {
  const std::string muxer = MuxerFor(path);
  if (width <= 0 || height <= 0 || width % 2 != 0 || height % 2 != 0) {
    throw Error(Str() << path << ": H.264 takes frames of even width and height, not " << width << "x" << height);
  }
  if (!(options.fps > 0 && options.fps <= 1000)) throw Error(Str() << path << ": a frame rate of " << options.fps);
  if (!(options.quantizer >= 0 && options.quantizer <= 50)) throw Error(path + ": the quantizer is 0..50");
  if (!(options.max_bitrate_kbps >= 100 && options.max_bitrate_kbps <= 2'000'000)) {
    throw Error(path + ": the most bits per second is 100..2000000 kbit/s");
  }
  // The path goes into a pipeline description, quoted: a quote or backslash in it cannot.
  if (part_.find_first_of("\"\\") != std::string::npos) {
    throw Error(path + ": a video path with a quote or backslash in it cannot be handed to GStreamer");
  }
  const std::string pipeline =
      Str() << "appsrc ! videoconvert ! video/x-raw,format=I420 ! x264enc pass=qual quantizer=" << options.quantizer
            << " bitrate=" << options.max_bitrate_kbps << " speed-preset=" << options.speed_preset << " ! " << muxer
            << " ! filesink location=\"" << part_ << "\"";
  // Frames go in as BGR: videoconvert then maps them to H.264's video range and tags the stream so,
  // which every decoder reads back (gray handed over as it is would be tagged video range without
  // being mapped to it, and come back darker or brighter).
  if (!writer_.open(pipeline, cv::CAP_GSTREAMER, 0, options.fps, cv::Size(width, height), true)) {
    throw Error(path +
                ": GStreamer cannot encode H.264 here (its x264enc is in gstreamer1.0-plugins-ugly) or cannot "
                "write there");
  }
}

H264FileWriter::~H264FileWriter() {
  if (finished_) return;
  try {
    Finish();
  } catch (const std::exception& e) {
    STITCH_LOG(WARNING) << e.what();
  }
}

void H264FileWriter::Write(const cv::Mat& gray) {
  if (finished_) throw Error(path_ + ": written to after it was finished");
  if (gray.cols != width_ || gray.rows != height_ || gray.type() != CV_8UC1) {
    throw Error(Str() << path_ << ": a frame of " << gray.cols << "x" << gray.rows << " (type " << gray.type()
                      << ") in a video of " << width_ << "x" << height_ << " gray frames");
  }
  cv::cvtColor(gray, bgr_, cv::COLOR_GRAY2BGR);
  writer_.write(bgr_);
  ++frames_;
}

void H264FileWriter::Finish() {
  if (finished_) return;
  finished_ = true;
  writer_.release();  // end of stream: the muxer writes its index
  std::error_code error;
  const auto size = fs::file_size(part_, error);
  if (error || size == 0 || frames_ == 0) {
    fs::remove(part_, error);
    throw Error(Str() << path_ << ": the encoder wrote no video (" << frames_ << " frames given)");
  }
  fs::rename(part_, path_, error);
  if (error) throw Error(path_ + ": cannot name the finished video: " + error.message());
}

}  // namespace stitch
