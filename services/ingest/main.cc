// stitch-ingest: publishes frames from a live camera, a dataset, a video or the synthetic flight
// on the bus.

#include <cstdio>

#include "services/common/convert.h"
#include "services/common/service_main.h"
#include "services/ingest/ingest_service.h"
#include "services/ingest/live_gnss.h"
#include "stitch/io/live_capture.h"
#include "stitch/records/source_record.h"
#include "stitch/source/read_ahead.h"
#include "stitch/source/source.h"
#include "stitch/util/options.h"

int main(int argc, char** argv) {
  using namespace stitch;
  ServiceCommandLine common;
  SourceSpec source;
  std::string pacing, encoding, record;
  ArgParser args("stitch-ingest",
                 "Publishes camera frames on <agent>/FRAME: from a live camera (--live), a dataset (TUM RGB-D, "
                 "EuRoC, KITTI, an image folder, a video) or, without either, the synthetic UAV survey flight.");
  common.Register(&args);
  AddSourceOptions(&args, &source);
  args.AddOption("--pacing", &pacing, "MODE", "lockstep or realtime (overrides the config)");
  args.AddOption("--encoding", &encoding, "ENC", "gray8, jpeg or auto (overrides the config)");
  args.AddOption("--record", &record, "FILE",
                 "write how the source kept the camera's pace (frames sent, frames late) to FILE (JSON) when it ends");
  if (!args.Parse(argc, argv)) return args.exit_code();
  std::vector<std::string> settings = common.settings;
  if (args.Given("--pacing")) settings.push_back(TextSetting("ingest.pacing", pacing));
  if (args.Given("--encoding")) settings.push_back(TextSetting("ingest.encoding", encoding));
  return RunService(
      "ingest", common, settings,
      [&](ServiceProcess& process) {
        CheckSourceSpec(source);
        source.synthetic = process.config.synthetic;
        source.max_working_pixels = process.config.ingest.max_working_pixels;
        source.video_deblocking = process.config.ingest.video_deblocking;
        if (source.live_uri.empty() && source.dataset_path.empty()) source.live_uri = process.config.ingest.live;
        IngestService ingest(process.lcm, process.frame_url(), process.publisher, process.config.ingest,
                             process.frame_publisher);
        Heartbeat heartbeat(process.publisher, "ingest", [&] {
          return Heartbeat::Counts{ingest.frames_published(), ingest.frames_published(), ingest.rejected()};
        });
        bus::Dispatcher dispatcher(process.lcm);
        dispatcher.Start();
        heartbeat.Start();
        // A live camera's frames do not wait: open it once a tracker listens (or the wait is over).
        if (!source.live_uri.empty()) ingest.WaitForTracker(process.stop);
        // A live receiver's fixes carry the wall clock at their arrival: only live frames share it.
        std::unique_ptr<LiveGnssReceiver> gnss;
        if (const IngestOptions& o = process.config.ingest; !o.gnss_receiver.empty()) {
          if (source.live_uri.empty() || LiveClock(source.live_uri, source.live_clock) != "wall") {
            throw Error(
                "ingest.gnss_receiver needs a live camera whose frames carry the wall clock (--live, --live-clock "
                "wall): a recorded sequence's GNSS comes from its gnss.csv, .SRT or photos' EXIF tags");
          }
          const std::string channel = bus::Channel(process.publisher->agent(), bus::kGnss);
          std::optional<Secret> signing_key;
          if (!o.gnss_signing_key_file.empty()) {
            signing_key = LoadSecretFile(o.gnss_signing_key_file, "MAVLink signing key",
                                         "write the flight controller's key there as 64 hex digits");
          }
          gnss = OpenLiveGnssReceiver(
              o.gnss_receiver, o.gnss_latency_s,
              [&process, channel](const GnssFix& fix) {
                stitch::gnss_fix_t message = ToMessage(fix);
                process.publisher->Publish(channel, &message);
              },
              signing_key, o.gnss_signing_state_file);
        }
        FailureSchedule spoil;
        auto sequence = ReadAhead(OpenSource(source, &spoil), process.config.ingest.read_ahead_frames);
        heartbeat.SetState(stitch::service_status_t::STATE_RUNNING, sequence->description());
        const IngestSummary summary = ingest.Play(*sequence, spoil, process.stop, SourceGnss(source).fixes);
        if (gnss) {
          STITCH_LOG(INFO) << "published " << gnss->Describe();
        }
        gnss.reset();
        if (!record.empty()) {
          SourceRecord written;
          written.frames_published = summary.frames_published;
          written.frames_late = summary.frames_late;
          written.most_late_s = summary.most_late_s;
          written.seconds = summary.seconds;
          WriteSourceRecord(record, written);
        }
        heartbeat.SetState(stitch::service_status_t::STATE_FINISHED);
        heartbeat.Stop();
        dispatcher.Stop();
        return summary.stopped ? 130 : 0;
      },
      FrameBus::kOpen);
}
