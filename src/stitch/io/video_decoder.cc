#include "stitch/io/video_decoder.h"

#include <cmath>

extern "C" {
#include <libavcodec/avcodec.h>
#include <libavformat/avformat.h>
#include <libavutil/imgutils.h>
#include <libavutil/pixdesc.h>
#include <libswscale/swscale.h>
}

#include "stitch/util/error.h"

namespace stitch {
namespace {

// Frames larger than this (8K is 33 MP) are refused: a damaged or hostile header, not a camera.
constexpr int64_t kMaxPixels = 100'000'000;

std::string AvError(int code) {
  char text[AV_ERROR_MAX_STRING_SIZE] = {};
  av_strerror(code, text, sizeof(text));
  return text;
}

// Whether the format's first plane is 8-bit luma, and whether it spans the full 0-255 range.
bool LumaPlane(AVPixelFormat format, AVColorRange range, bool* full_range) {
  switch (format) {
    case AV_PIX_FMT_YUVJ420P:
    case AV_PIX_FMT_YUVJ422P:
    case AV_PIX_FMT_YUVJ444P:
    case AV_PIX_FMT_YUVJ440P:
    case AV_PIX_FMT_GRAY8:
      *full_range = range != AVCOL_RANGE_MPEG;
      return true;
    case AV_PIX_FMT_YUV420P:
    case AV_PIX_FMT_YUV422P:
    case AV_PIX_FMT_YUV444P:
    case AV_PIX_FMT_YUV440P:
    case AV_PIX_FMT_YUV411P:
    case AV_PIX_FMT_YUV410P:
    case AV_PIX_FMT_YUVA420P:
    case AV_PIX_FMT_NV12:
    case AV_PIX_FMT_NV21:
    case AV_PIX_FMT_NV16:
      *full_range = range == AVCOL_RANGE_JPEG;  // unstated: video range, as FFmpeg takes it
      return true;
    default:
      return false;
  }
}

}  // namespace

struct VideoDecoder::Libav {
  AVFormatContext* format = nullptr;
  AVCodecContext* codec = nullptr;
  AVPacket* packet = nullptr;
  AVFrame* frame = nullptr;
  SwsContext* sws = nullptr;
  int stream = -1;
  int64_t start_time = AV_NOPTS_VALUE;
  AVRational time_base{1, 1};

  ~Libav() {
    sws_freeContext(sws);
    av_frame_free(&frame);
    av_packet_free(&packet);
    avcodec_free_context(&codec);
    avformat_close_input(&format);
  }
};

VideoDecoder::VideoDecoder(const std::string& path, int64_t skip_deblocking_from_pixels)
    : av_(std::make_unique<Libav>()), path_(path) {
  av_log_set_level(AV_LOG_ERROR);
  int code = avformat_open_input(&av_->format, path.c_str(), nullptr, nullptr);
  if (code < 0) throw Error(path + ": cannot open video: " + AvError(code));
  code = avformat_find_stream_info(av_->format, nullptr);
  if (code < 0) throw Error(path + ": cannot read the video's streams: " + AvError(code));
  const AVCodec* decoder = nullptr;
  av_->stream = av_find_best_stream(av_->format, AVMEDIA_TYPE_VIDEO, -1, -1, &decoder, 0);
  if (av_->stream < 0 || !decoder) {
    throw Error(path + (av_->stream == AVERROR_DECODER_NOT_FOUND ? ": no decoder for its video (unsupported codec)"
                                                                 : ": no video stream"));
  }
  AVStream* stream = av_->format->streams[av_->stream];
  av_->codec = avcodec_alloc_context3(decoder);
  if (!av_->codec || avcodec_parameters_to_context(av_->codec, stream->codecpar) < 0) {
    throw Error(path + ": cannot set up the decoder");
  }
  width_ = av_->codec->width;
  height_ = av_->codec->height;
  if (width_ <= 0 || height_ <= 0 || static_cast<int64_t>(width_) * height_ > kMaxPixels) {
    throw Error(path + ": the video's frames are " + std::to_string(width_) + "x" + std::to_string(height_) +
                " (not a size stitch reads)");
  }
  av_->codec->thread_count = 0;  // as many as the machine has: frames are decoded ahead
  av_->codec->thread_type = FF_THREAD_FRAME | FF_THREAD_SLICE;
  deblocking_ = static_cast<int64_t>(width_) * height_ < skip_deblocking_from_pixels;
  if (!deblocking_) av_->codec->skip_loop_filter = AVDISCARD_ALL;
  code = avcodec_open2(av_->codec, decoder, nullptr);
  if (code < 0) throw Error(path + ": cannot open its " + decoder->name + " decoder: " + AvError(code));
  av_->packet = av_packet_alloc();
  av_->frame = av_frame_alloc();
  if (!av_->packet || !av_->frame) throw Error(path + ": out of memory opening the video");
  av_->time_base = stream->time_base;
  av_->start_time = stream->start_time;
  const AVRational rate = av_guess_frame_rate(av_->format, stream, nullptr);
  if (rate.num > 0 && rate.den > 0) fps_ = av_q2d(rate);
  if (stream->nb_frames > 0) {
    count_ = stream->nb_frames;
  } else if (fps_ > 0 && stream->duration != AV_NOPTS_VALUE && stream->duration > 0) {
    count_ = std::llround(static_cast<double>(stream->duration) * av_q2d(stream->time_base) * fps_);
  } else if (fps_ > 0 && av_->format->duration > 0) {
    count_ = std::llround(static_cast<double>(av_->format->duration) / AV_TIME_BASE * fps_);
  }
}

VideoDecoder::~VideoDecoder() = default;

bool VideoDecoder::NextFrame() {
  int errors_in_a_row = 0;  // a decoder that fails on and on ends the clip
  while (!ended_) {
    const int received = avcodec_receive_frame(av_->codec, av_->frame);
    if (received == 0) {
      if (av_->frame->width != width_ || av_->frame->height != height_) {
        ++skipped_frames_;  // the calibration is of the first size: such a frame cannot be used
        av_frame_unref(av_->frame);
        continue;
      }
      return true;
    }
    if (received == AVERROR_EOF || (flushing_ && received == AVERROR(EAGAIN))) {
      ended_ = true;
      break;
    }
    if (received != AVERROR(EAGAIN)) {
      ++skipped_frames_;  // a frame the decoder could not finish: the next one may do
      if (++errors_in_a_row > 1000) ended_ = true;
      continue;
    }
    // The decoder wants input: the next packet of the video stream, or the end.
    const int read = av_read_frame(av_->format, av_->packet);
    if (read < 0) {
      flushing_ = true;
      avcodec_send_packet(av_->codec, nullptr);
      continue;
    }
    if (av_->packet->stream_index == av_->stream && avcodec_send_packet(av_->codec, av_->packet) < 0) {
      ++skipped_packets_;
    }
    av_packet_unref(av_->packet);
  }
  return false;
}

void VideoDecoder::ToGray(cv::Mat* gray) {
  const AVFrame& f = *av_->frame;
  bool full_range = false;
  const auto format = static_cast<AVPixelFormat>(f.format);
  if (LumaPlane(format, f.color_range, &full_range)) {
    const cv::Mat luma(height_, width_, CV_8UC1, f.data[0], static_cast<size_t>(f.linesize[0]));
    if (full_range) {
      luma.copyTo(*gray);
    } else {
      luma.convertTo(*gray, CV_8U, 255.0 / 219.0, -16.0 * 255.0 / 219.0);
    }
    return;
  }
  // Any other format (RGB, 10-bit, palette) through FFmpeg's own conversion to grey.
  av_->sws = sws_getCachedContext(av_->sws, width_, height_, format, width_, height_, AV_PIX_FMT_GRAY8, SWS_POINT,
                                  nullptr, nullptr, nullptr);
  if (!av_->sws)
    throw Error(path_ + ": frames in " + (av_get_pix_fmt_name(format) ? av_get_pix_fmt_name(format) : "?") +
                " cannot be made grey");
  gray->create(height_, width_, CV_8UC1);
  uint8_t* planes[4] = {gray->data, nullptr, nullptr, nullptr};
  int strides[4] = {static_cast<int>(gray->step[0]), 0, 0, 0};
  sws_scale(av_->sws, f.data, f.linesize, 0, height_, planes, strides);
}

bool VideoDecoder::Read(cv::Mat* gray, int64_t* time_ns) {
  if (!NextFrame()) return false;
  *gray = cv::Mat();  // a buffer of its own: a frame handed out before may still be held
  ToGray(gray);
  const int64_t t = av_->frame->best_effort_timestamp;
  if (t == AV_NOPTS_VALUE) {
    *time_ns = -1;
  } else {
    const int64_t start = av_->start_time != AV_NOPTS_VALUE ? av_->start_time : 0;
    *time_ns = av_rescale_q(t - start, av_->time_base, AVRational{1, 1'000'000'000});
  }
  av_frame_unref(av_->frame);
  return true;
}

bool VideoDecoder::Skip() {
  if (!NextFrame()) return false;
  av_frame_unref(av_->frame);
  return true;
}

}  // namespace stitch
