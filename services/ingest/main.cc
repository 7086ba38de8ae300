// stitch-ingest: publishes frames from a dataset, a video or the synthetic flight on the bus.

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
                 "Publishes camera frames on <agent>/FRAME: from a dataset (TUM RGB-D, EuRoC, KITTI, an image "
                 "folder, a video) or, without --dataset, the synthetic UAV survey flight.");
  common.Register(&args);
  args.AddOption("--dataset", &source.dataset_path, "PATH", "dataset folder or video file (default: synthetic flight)");
  args.AddOption("--calib", &source.calibration_path, "FILE", "calibration overriding the dataset's own");
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
    FailureSchedule spoil;
    auto sequence = OpenSource(source, &spoil);

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
