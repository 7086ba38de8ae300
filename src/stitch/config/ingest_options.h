#pragma once
// Settings of the ingest service (the `ingest:` section of a stitch config).

#include <string>

namespace stitch {

// Why `receiver` is not an ingest.gnss_receiver setting (empty when it is, or is empty).
inline std::string WhyNotAGnssReceiver(const std::string& receiver) {
  if (receiver.empty() || receiver == "gpsd") return "";
  const auto address_after = [&](const std::string& scheme) {
    return receiver.rfind(scheme, 0) == 0 && receiver.find(':', scheme.size()) != std::string::npos;
  };
  if (address_after("gpsd:") || address_after("mavlink:")) return "";
  if (receiver.rfind("mavlink-serial:/", 0) == 0) return "";
  return "ingest.gnss_receiver must be gpsd, gpsd:HOST:PORT, mavlink:ADDRESS:PORT (an empty address: every "
         "interface, e.g. mavlink::14550) or mavlink-serial:DEVICE[:BAUD] (e.g. mavlink-serial:/dev/ttyACM0:57600), "
         "not '" +
         receiver + "'";
}

// The modes of a video file's deblocking filter (IngestOptions::video_deblocking, SourceSpec's).
inline bool IsVideoDeblockingMode(const std::string& mode) {
  return mode == "auto" || mode == "on" || mode == "off";
}

struct IngestOptions {
  // A live camera (stitch-ingest --live takes precedence): a V4L2 device, a GStreamer pipeline or
  // a stream URL. Here rather than on the command line where a pipeline's spaces would not survive
  // (a systemd unit's arguments).
  std::string live;
  std::string pacing = "lockstep";  // lockstep: wait for the tracker's ack; realtime: camera rate
  double speed = 1.0;               // realtime: playback speed factor (2 = twice as fast)
  // Frames of more pixels than this are reduced (area averaging, the aspect kept) before they are
  // sent, with their camera: the tracker, the mapper and the merger work at that size, and a 1080p
  // or 4K camera costs about what a 0.5 MP one does (docs/speed.md). 518,400 is 960x540, which
  // 1080p and 4K reach by exact halvings alone (a fractional step costs 5-20 times more). 0:
  // frames as they come.
  int max_working_pixels = 518400;
  // A video file's H.264/H.265 deblocking filter: on, off, or auto (off for frames that are
  // halved at least once for their working size, at least 4 x max_working_pixels: 1080p and 4K).
  // Off saves about a fifth of a frame's decoding; the 2x2 averages of a halving smooth the block
  // edges the filter would have smoothed (docs/speed.md).
  std::string video_deblocking = "auto";
  // A recorded source (a video, image files, the synthetic flight) is read by a thread of its own
  // at most this many frames ahead of the frame going out (0: read as each is sent): reading a
  // frame that meets a busy moment of the machine does not make it late (source/read_ahead.h).
  int read_ahead_frames = 8;
  std::string encoding = "auto";  // gray8 (raw), jpeg, or auto (see ChooseFrameEncoding)
  int jpeg_quality = 92;
  double ack_timeout_s = 0.25;         // lockstep: re-send a frame not acknowledged within this
  int max_resends = 40;                // lockstep: then give up on that frame and go on (10 s by default)
  double wait_for_tracker_s = 30.0;    // every source: how long to wait for a tracker at start
  std::string failure_style = "blur";  // datasets: black, or blur (heavy blur and a jump)
  int failure_seed = 1;
  // A live camera's GNSS receiver (services/ingest/live_gnss.h): "gpsd" or "gpsd:HOST:PORT" (a
  // receiver gpsd serves), "mavlink:ADDRESS:PORT" (a flight controller's MAVLink telemetry on
  // UDP, e.g. "mavlink::14550") or "mavlink-serial:DEVICE[:BAUD]" (from its serial port). Its fixes go on <agent>/GNSS
  // on the frames' wall clock: the receiver's own time of each fix carried onto it by the
  // quickest arrival (ReceiverClock; a fix without a time: its arrival), less gnss_latency_s.
  // Empty: none.
  std::string gnss_receiver;
  double gnss_latency_s = 0.0;
  // MAVLink receivers: the flight controller's MAVLink 2 signing key, as 64 hex digits in a file
  // only its owner may read; with it only fixes signed with that key are taken. Empty: none.
  std::string gnss_signing_key_file;
  // With a signing key: where the newest signature timestamp taken is kept across runs (relative
  // to the ingest's working directory; the systemd unit's is /var/lib/stitch). Empty: not kept.
  std::string gnss_signing_state_file = "mavlink-signing.state";

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("live", live,
      "a live camera when --live is not given: V4L2 device, GStreamer pipeline ('... ! appsink') or stream URL "
      "(empty: none)");
    v("pacing", pacing, "lockstep (reproducible: waits for the tracker) or realtime (drops if it lags)");
    v("speed", speed, "realtime playback speed factor");
    v("max_working_pixels", max_working_pixels,
      "frames of more pixels than this are reduced (aspect kept) before they are sent, with their camera: the "
      "system works at that size (0: as they come)");
    v("video_deblocking", video_deblocking,
      "video files: the decoder's deblocking filter, on, off or auto (off for frames at least 4 x max_working_pixels, "
      "which are halved for their working size: about a fifth of an H.264 frame's decoding saved)");
    v("read_ahead_frames", read_ahead_frames,
      "recorded sources: frames read ahead of the one going out, by a thread of their own (0: each read as it is "
      "sent)");
    v("encoding", encoding,
      "frame encoding on the bus: gray8, jpeg, or auto (gray8 unless the UDP receive buffer is too small for raw "
      "frames)");
    v("jpeg_quality", jpeg_quality, "JPEG quality, 1-100");
    v("ack_timeout_s", ack_timeout_s, "lockstep: re-send a frame not acknowledged within this, seconds");
    v("max_resends", max_resends, "lockstep: re-sends before giving up on a frame");
    v("wait_for_tracker_s", wait_for_tracker_s,
      "how long to wait for a tracker at start, seconds (lockstep playback then fails; real-time and live sources go "
      "on "
      "anyway)");
    v("failure_style", failure_style, "how induced failures spoil dataset frames: black or blur");
    v("failure_seed", failure_seed, "seed of the spoiled frames");
    v("gnss_receiver", gnss_receiver,
      "live cameras: the GNSS receiver whose fixes go on <agent>/GNSS, on the frames' clock: gpsd[:HOST:PORT] "
      "(localhost:2947), mavlink:ADDRESS:PORT (a flight controller's telemetry on UDP, e.g. mavlink::14550) or "
      "mavlink-serial:DEVICE[:BAUD] (from its serial port, e.g. mavlink-serial:/dev/ttyACM0:57600) (empty: none)");
    v("gnss_latency_s", gnss_latency_s,
      "how much older a live receiver's fix is than its quickest arrival (its arrival where it states no time), "
      "seconds");
    v("gnss_signing_key_file", gnss_signing_key_file,
      "mavlink receivers: a file (mode 0600) holding the flight controller's MAVLink 2 signing key as 64 hex digits "
      "(MAVProxy's `signing setup PASSPHRASE` key: `printf %s PASSPHRASE | sha256sum`); only fixes signed with it "
      "are taken (empty: signatures are not checked)");
    v("gnss_signing_state_file", gnss_signing_state_file,
      "with a signing key: the file where the newest signature timestamp taken is kept, so that frames recorded in "
      "an earlier run are refused after a restart too (relative to the ingest's working directory; empty: not kept)");
  }

  bool Check(std::string* why) const {
    auto fail = [&](const std::string& m) {
      if (why) *why = m;
      return false;
    };
    if (pacing != "lockstep" && pacing != "realtime") return fail("ingest.pacing must be lockstep or realtime");
    if (!(speed > 0 && speed <= 100)) return fail("ingest.speed must be in (0, 100]");
    if (max_working_pixels < 0) return fail("ingest.max_working_pixels must be >= 0 (0: frames as they come)");
    if (!IsVideoDeblockingMode(video_deblocking)) return fail("ingest.video_deblocking must be auto, on or off");
    if (max_working_pixels > 0 && max_working_pixels < 10000) {
      return fail("ingest.max_working_pixels must be 0 or at least 10000 (100x100)");
    }
    if (encoding != "gray8" && encoding != "jpeg" && encoding != "auto")
      return fail("ingest.encoding must be gray8, jpeg or auto");
    if (jpeg_quality < 1 || jpeg_quality > 100) return fail("ingest.jpeg_quality must be in [1, 100]");
    if (read_ahead_frames < 0 || read_ahead_frames > 1000) return fail("ingest.read_ahead_frames must be in [0, 1000]");
    if (!(ack_timeout_s > 0)) return fail("ingest.ack_timeout_s must be > 0");
    if (max_resends < 0) return fail("ingest.max_resends must be >= 0");
    if (!(wait_for_tracker_s >= 0)) return fail("ingest.wait_for_tracker_s must be >= 0");
    if (failure_style != "black" && failure_style != "blur") return fail("ingest.failure_style must be black or blur");
    if (const std::string why_not = WhyNotAGnssReceiver(gnss_receiver); !why_not.empty()) return fail(why_not);
    if (!(gnss_latency_s >= 0 && gnss_latency_s <= 10)) return fail("ingest.gnss_latency_s must be in [0, 10]");
    return true;
  }
};

}  // namespace stitch
