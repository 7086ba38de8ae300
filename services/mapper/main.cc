// stitch-mapper: local mapping of the keyframes on <agent>/KEYFRAME.

#include "services/common/service_main.h"
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
  return RunService("mapper", common, common.settings, [&](ServiceProcess& process) {
    const Vocabulary vocabulary = LoadVocabulary(process.config);
    MapperService mapper(process.lcm, process.publisher, process.config.mapper, process.config.tracker.tracking.orb,
                         &vocabulary, record_dir);
    // The bus stays up while the mapper stops: it answers the merger's last requests.
    process.RunUntilStopped(mapper, ServiceProcess::StopOrder::kServiceFirst);
    STITCH_LOG(INFO) << "stopped after " << mapper.keyframes_mapped() << " keyframes";
    return 0;
  });
}
