// stitch mosaic: a run's orthomosaic as a GeoTIFF.

#include <cstdio>
#include <filesystem>

#include "stitch/config/stitch_config.h"
#include "stitch/util/args.h"
#include "stitch/util/error.h"
#include "stitch/util/text_file.h"
#include "tools/stitch/commands.h"
#include "tools/stitch/launch/run_mosaic.h"

namespace fs = std::filesystem;

namespace stitch {

int MosaicCommand(int argc, char** argv) {
  std::vector<std::string> positional, settings;
  std::string out, images, pictures = "auto";
  bool force = false;
  double gsd = -1;
  ArgParser args(
      "stitch mosaic",
      "Lays the keyframes of a run's largest map on its ground, each mosaic pixel from the keyframe that "
      "sees it nearest its nadir, and writes the orthomosaic as a GeoTIFF (red, green, blue and alpha; tiled, "
      "with overviews). A map the run placed on Earth by its GNSS fixes is north up in WGS 84 / UTM, in "
      "metres (gdalinfo and any GIS read it); otherwise the mosaic lies in the map's own frame, levelled on "
      "its points, in its units. The keyframes' pictures come from what the run played (the synthetic "
      "flight rendered again, the dataset's images, the video). Beside the GeoTIFF, FILE.json holds the "
      "figures; for the synthetic flight also the mosaic's error against the world's true orthophoto "
      "(checkpoints) and the share of the surveyed ground it covers.");
  args.AddPositional(&positional, "RUN_DIR", "the run folder", 1);
  args.AddOption("--out", &out, "FILE", "the GeoTIFF to write (default: RUN_DIR/ortho.tif)");
  args.AddOption(
      "--gsd", &gsd, "M",
      "ground sample distance, metres a pixel on Earth (the map's units otherwise); default merger.mosaic.gsd_m");
  args.AddOption("--images", &images, "PATH", "the flight's images, where they moved (default: the run's --dataset)");
  args.AddOption("--pictures", &pictures, "WHICH",
                 "source (the flight's own images), received (the reduced keyframe pictures the ground received over "
                 "the link, keyframe_images/: a live camera's run, a ground station without the recording) or auto "
                 "(the flight's where they are at hand; default)");
  args.AddOption("--set", &settings, "KEY=VALUE",
                 "a setting over the run's config.yaml, e.g. merger.mosaic.tile_px=512");
  args.AddFlag(
      "--force", &force,
      "make a mosaic of a map that is not a ground seen from above too (a room, a street: its points lie "
      "further from their plane than merger.mosaic.live_max_relief of the cameras' height; refused otherwise)");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    if (positional.size() != 1) throw Error("give the run folder: stitch mosaic RUN_DIR");
    const std::string run_dir = positional[0];
    if (!fs::is_directory(run_dir)) throw Error(run_dir + " is not a run folder");
    if (gsd >= 0) settings.push_back("merger.mosaic.gsd_m=" + std::to_string(gsd));
    if (force) settings.push_back("merger.mosaic.live_max_relief=0");
    const fs::path config_path = fs::path(run_dir) / "config.yaml";
    const StitchConfig config =
        LoadStitchConfig(fs::exists(config_path) ? config_path.string() : std::string(), settings);
    SourceSpec source = SourceOfRun(run_dir);
    if (!images.empty()) {
      source.dataset_path = images;
      source.live_uri.clear();  // a live flight recorded elsewhere too
    }
    if (out.empty()) out = (fs::path(run_dir) / "ortho.tif").string();
    const RunMosaic mosaic = MakeRunMosaic(run_dir, source, config.merger.mosaic, out, ParseMosaicPictures(pictures));
    const std::string figures = fs::path(out).replace_extension(".json").string();
    WriteFileAtomically(figures, mosaic.ToJson().dump(1) + "\n");
    for (const std::string& line : mosaic.Summary()) std::printf("%s\n", line.c_str());
    std::printf("  figures           %s\n", figures.c_str());
    if (mosaic.truth) {
      std::printf("  checkpoints       %s\n", fs::path(out).replace_extension(".checkpoints.csv").c_str());
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch mosaic: %s\n", e.what());
    return 1;
  }
}

}  // namespace stitch
