// stitch-ingest: publishes frames from a live camera, a dataset, a video or the synthetic flight
// on the bus.

#include <cstdio>

#include "services/common/bus.h"
#include "services/common/service.h"
#include "services/config/stitch_config.h"
#include "services/ingest/ingest_service.h"
#include "stitch/source/source.h"
#include "stitch/util/options.h"

int main(int argc, char** argv) {
  using namespace stitch;
  ServiceCommandLine common;
  SourceSpec source;
  std::string pacing, encoding;
  ArgParser args("stitch-ingest",
                 "Publishes camera frames on <agent>/FRAME: from a live camera (--live), a dataset (TUM RGB-D, "
                 "EuRoC, KITTI, an image folder, a video) or, without either, the synthetic UAV survey flight.");
  common.Register(&args);
  args.AddOption("--live", &source.live_uri, "URI",
                 "a live camera: a V4L2 device (/dev/video0), a GStreamer pipeline ('... ! appsink') or a stream URL "
                 "(rtsp://, udp://); needs --calib. Frames go out as they come, the newest when the tracker lags");
  args.AddOption("--dataset", &source.dataset_path, "PATH", "dataset folder or video file (default: synthetic flight)");
  args.AddOption("--calib", &source.calibration_path, "FILE",
                 "calibration overriding the dataset's own (required with --live)");
  args.AddOption("--failures", &source.failures, "SPEC",
                 "frames to make unusable: FRAME:LENGTH,... or none; 'default' = 3 gusts on the synthetic flight, none "
                 "on datasets");
  args.AddOption("--max-frames", &source.max_frames, "N", "play at most N frames (-1: all)");
  args.AddOption("--start-frame", &source.start_frame, "N", "skip the first N frames");
  args.AddOption("--pacing", &pacing, "MODE", "lockstep or realtime (overrides the config)");
  args.AddOption("--encoding", &encoding, "ENC", "gray8, jpeg or auto (overrides the config)");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    common.Apply("ingest");
    std::vector<std::string> settings = common.settings;
    if (args.Given("--pacing")) settings.push_back(TextSetting("ingest.pacing", pacing));
    if (args.Given("--encoding")) settings.push_back(TextSetting("ingest.encoding", encoding));
    const StitchConfig config = LoadStitchConfig(common.config_path, settings);
    source.synthetic = config.synthetic;
    if (source.live_uri.empty() && source.dataset_path.empty()) source.live_uri = config.ingest.live;
    const auto& stop = InstallStopSignals();
    auto lcm = bus::OpenLcm(common.lcm_url);
    bus::Publisher publisher(lcm.get(), common.agent);
    IngestService ingest(lcm.get(), common.lcm_url, &publisher, config.ingest);
    Heartbeat heartbeat(&publisher, "ingest", [&] {
      return Heartbeat::Counts{ingest.frames_published(), ingest.frames_published(), ingest.rejected()};
    });
    bus::Dispatcher dispatcher(lcm.get());
    dispatcher.Start();
    heartbeat.Start();
    // A live camera's frames do not wait: open it once a tracker listens (or the wait is over).
    if (!source.live_uri.empty()) ingest.WaitForTracker(stop);
    FailureSchedule spoil;
    auto sequence = OpenSource(source, &spoil);
    heartbeat.SetState(stitch::service_status_t::STATE_RUNNING, sequence->description());
    const IngestSummary summary = ingest.Play(*sequence, spoil, stop);
    heartbeat.SetState(stitch::service_status_t::STATE_FINISHED);
    heartbeat.Stop();
    dispatcher.Stop();
    return summary.stopped ? 130 : 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch-ingest: %s\n", e.what());
    return 1;
  }
}
