// stitch render: writes the synthetic flight as an image folder (PNG, camera.yaml,
// groundtruth.txt), which `stitch run --dataset` and other SLAM systems can read.

#include <cstdio>
#include <filesystem>

#include <opencv2/imgcodecs.hpp>

#include "stitch/config/stitch_config.h"
#include "stitch/io/calibration.h"
#include "stitch/io/image_file.h"
#include "stitch/source/source.h"
#include "stitch/util/args.h"
#include "stitch/util/error.h"
#include "stitch/util/options.h"
#include "stitch/util/time.h"
#include "tools/stitch/commands.h"

namespace fs = std::filesystem;

namespace stitch {

int RenderCommand(int argc, char** argv) {
  std::string out_dir, config_path;
  std::vector<std::string> settings;
  SourceSpec spec;
  ArgParser args("stitch render",
                 "Renders the synthetic UAV survey flight to an image folder: frames as PNG named by timestamp, "
                 "camera.yaml and groundtruth.txt (TUM).");
  args.AddOption("--out", &out_dir, "DIR", "output folder (required)");
  args.AddOption("--config", &config_path, "FILE", "YAML settings; its synthetic: section shapes the flight");
  args.AddOption("--set", &settings, "KEY=VALUE", "a setting over the file, e.g. synthetic.flight.altitude_m=40");
  AddSourceOptions(&args, &spec, kFailuresFlag | kMaxFramesFlag);
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    if (out_dir.empty()) throw Error("--out DIR is required");
    spec.synthetic = LoadStitchConfig(config_path, settings).synthetic;
    FailureSchedule unused;
    auto sequence = OpenSource(spec, &unused);
    fs::create_directories(out_dir);
    SaveCalibration(sequence->camera(), (fs::path(out_dir) / "camera.yaml").string());
    const Stopwatch clock;
    SequenceFrame frame;
    Trajectory truth;
    const int total = sequence->size();
    while (sequence->Next(&frame)) {
      const std::string name = FormatSeconds(frame.t_ns) + ".png";
      WritePng((fs::path(out_dir) / name).string(), frame.image);
      if (const auto pose = sequence->ground_truth().PoseAt(frame.t_ns)) truth.Add({frame.t_ns, *pose});
      if ((frame.index + 1) % 50 == 0 || frame.index + 1 == total) {
        std::printf("\r  rendered %d/%d", frame.index + 1, total);
        std::fflush(stdout);
      }
    }
    truth.WriteTum((fs::path(out_dir) / "groundtruth.txt").string());
    std::printf("\nwrote %d frames to %s in %.1f s (%s)\n", total, out_dir.c_str(), clock.ElapsedSeconds(),
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
