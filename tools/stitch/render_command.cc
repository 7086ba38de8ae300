// stitch render: writes the synthetic flight as an image folder (PNG, camera.yaml,
// groundtruth.txt) or an H.264 video, which `stitch run --dataset` and other SLAM systems can read.

#include <cstdio>
#include <filesystem>
#include <memory>

#include <opencv2/imgcodecs.hpp>

#include "stitch/config/stitch_config.h"
#include "stitch/io/calibration.h"
#include "stitch/io/image_file.h"
#include "stitch/io/output_frames.h"
#include "stitch/io/video_file_writer.h"
#include "stitch/source/source.h"
#include "stitch/util/args.h"
#include "stitch/util/error.h"
#include "stitch/util/options.h"
#include "stitch/util/time.h"
#include "tools/stitch/commands.h"

namespace fs = std::filesystem;

namespace stitch {

int RenderCommand(int argc, char** argv) {
  std::string out, config_path;
  std::vector<std::string> settings;
  SourceSpec spec;
  H264FileOptions video;
  ArgParser args(
      "stitch render",
      "Renders the synthetic UAV survey flight to an image folder (frames as PNG named by timestamp, "
      "camera.yaml and groundtruth.txt, TUM) or, for --out FILE.mp4 (.mkv, .mov), to an H.264 video as "
      "an aircraft's camera records one, with FILE.yaml and FILE.groundtruth.txt beside it (GStreamer's "
      "x264enc: gstreamer1.0-plugins-ugly); the synthetic GNSS receiver's fixes go to gnss.csv (FILE.gnss.csv "
      "beside a video; synthetic.gnss.rate_hz=0: none).");
  args.AddOption("--out", &out, "DIR|FILE", "output folder, or a video file (.mp4, .mkv, .mov) (required)");
  args.AddOption("--config", &config_path, "FILE", "YAML settings; its synthetic: section shapes the flight");
  args.AddOption("--set", &settings, "KEY=VALUE", "a setting over the file, e.g. synthetic.flight.altitude_m=40");
  args.AddOption("--quantizer", &video.quantizer, "Q", "a video's H.264 constant quality, 0 (lossless) .. 50");
  args.AddOption("--max-bitrate", &video.max_bitrate_kbps, "KBPS",
                 "a video's most bits per second, kbit/s (default: 100000, an aircraft camera's 4K recording rate)");
  AddSourceOptions(&args, &spec, kFailuresFlag | kMaxFramesFlag);
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    if (out.empty()) throw Error("--out DIR|FILE is required");
    spec.synthetic = LoadStitchConfig(config_path, settings).synthetic;
    FailureSchedule unused;
    auto sequence = OpenSource(spec, &unused);
    const std::string ext = fs::path(out).extension().string();
    const bool to_video = ext == ".mp4" || ext == ".mkv" || ext == ".mov" || ext == ".m4v";
    fs::path calibration = fs::path(out) / "camera.yaml", truth_path = fs::path(out) / "groundtruth.txt";
    std::unique_ptr<H264FileWriter> writer;
    if (to_video) {
      if (fs::path(out).has_parent_path()) fs::create_directories(fs::path(out).parent_path());
      calibration = fs::path(out).replace_extension(".yaml");
      truth_path = fs::path(out).replace_extension(".groundtruth.txt");
      video.fps = sequence->nominal_fps();
      writer = std::make_unique<H264FileWriter>(out, sequence->camera().width(), sequence->camera().height(), video);
    } else {
      fs::create_directories(out);
    }
    SaveCalibration(sequence->camera(), calibration.string(), spec.synthetic.camera.rolling_shutter_line_us);
    const Stopwatch clock;
    SequenceFrame frame;
    Trajectory truth;
    const int total = sequence->size();
    while (sequence->Next(&frame)) {
      if (writer) {
        writer->Write(frame.image);
      } else {
        WritePng((fs::path(out) / (FormatSeconds(frame.t_ns) + ".png")).string(), frame.image);
      }
      if (const auto pose = sequence->ground_truth().PoseAt(frame.t_ns)) truth.Add({frame.t_ns, *pose});
      if ((frame.index + 1) % 50 == 0 || frame.index + 1 == total) {
        std::printf("\r  rendered %d/%d", frame.index + 1, total);
        std::fflush(stdout);
      }
    }
    if (writer) writer->Finish();
    truth.WriteTum(truth_path.string(), output_frames::kGroundTruth);
    // The receiver's fixes of the frames rendered, where `stitch run --dataset` looks for them.
    const GnssTrack gnss = SimulateGnssReceiver(truth, spec.synthetic.gnss, static_cast<uint64_t>(spec.synthetic.seed));
    if (!gnss.fixes.empty()) WriteGnssCsv(GnssFileBeside(out), gnss);
    std::printf("\nwrote %d frames to %s in %.1f s (%s)\n", total, out.c_str(), clock.ElapsedSeconds(),
                sequence->description().c_str());
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch render: %s\n", e.what());
    return 1;
  }
}

int ConfigCommand(int argc, char** argv) {
  std::string config_path;
  std::vector<std::string> settings;
  ArgParser args("stitch config",
                 "Prints the configuration with every setting and its meaning: the defaults, or a file's settings "
                 "merged over them (which also checks the file).");
  args.AddOption("--config", &config_path, "FILE", "a settings file to check and show resolved");
  args.AddOption("--set", &settings, "KEY=VALUE", "a setting over the file, checked and shown resolved");
  std::string calibration;
  args.AddOption("--calib", &calibration, "FILE",
                 "an ORB-SLAM settings file whose ORBextractor.* go over the file (as `stitch run --calib` does), "
                 "for the tracker and mapper of a deployment");
  std::string vocabulary;
  args.AddOption("--vocabulary", &vocabulary, "FILE", "the vocabulary setting (as `stitch run --vocabulary`)");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    const StitchConfig config = LoadStitchConfig(config_path, CommandLineSettings(calibration, vocabulary, settings));
    std::printf("# stitch settings%s. Any subset may be given to --config; unknown keys are errors.\n%s",
                config_path.empty() ? " (defaults)" : (" resolved from " + config_path).c_str(),
                DumpOptions(config).c_str());
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch config: %s\n", e.what());
    return 1;
  }
}

}  // namespace stitch
