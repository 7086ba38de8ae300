// stitch-mapper: local mapping of the keyframes on <agent>/KEYFRAME.

#include <cstdio>
#include <thread>

#include "services/common/bus.h"
#include "services/common/service.h"
#include "services/config/stitch_config.h"
#include "services/mapper/mapper_service.h"

int main(int argc, char** argv) {
  using namespace stitch;
  ServiceCommandLine common;
  std::string record_dir;
  ArgParser args("stitch-mapper",
                 "Builds the local map from the keyframes on <agent>/KEYFRAME (triangulation, local bundle "
                 "adjustment, culling) and publishes the changes on <agent>/LOCAL_MAP. Runs until SIGINT or SIGTERM.");
  common.Register(&args);
  args.AddOption("--record", &record_dir, "DIR", "at the end, write submaps.ply and keyframes.tsv to DIR");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    common.Apply("mapper");
    const StitchConfig config = LoadStitchConfig(common.config_path, common.settings);
    const Vocabulary vocabulary = LoadVocabulary(config);
    const auto& stop = InstallStopSignals();
    auto lcm = bus::OpenLcm(common.lcm_url);
    bus::Publisher publisher(lcm.get(), common.agent);
    MapperService mapper(lcm.get(), &publisher, config.mapper, config.tracker.tracking.orb, &vocabulary, record_dir);
    bus::Dispatcher dispatcher(lcm.get());
    dispatcher.Start();
    mapper.Start();
    STITCH_LOG(INFO) << "listening on " << common.lcm_url;
    while (!stop.load()) std::this_thread::sleep_for(std::chrono::milliseconds(50));
    // The bus stays up while the mapper stops: it answers the merger's last requests.
    mapper.Stop();
    dispatcher.Stop();
    STITCH_LOG(INFO) << "stopped after " << mapper.keyframes_mapped() << " keyframes";
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch-mapper: %s\n", e.what());
    return 1;
  }
}
