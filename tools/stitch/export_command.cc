// stitch export colmap: a run's merged map as a COLMAP sparse model on the flight's images.

#include <cstdio>
#include <filesystem>

#include "stitch/io/colmap_database.h"
#include "stitch/io/colmap_model.h"
#include "stitch/records/run_info.h"
#include "stitch/util/args.h"
#include "stitch/util/error.h"
#include "tools/stitch/commands.h"
#include "tools/stitch/launch/map_colours.h"

namespace fs = std::filesystem;

namespace stitch {

int ExportCommand(int argc, char** argv) {
  std::vector<std::string> positional;
  std::string images, out;
  ArgParser args("stitch export",
                 "Exports a run for other tools. `stitch export colmap RUN_DIR --out DIR` writes the run's largest "
                 "merged map as a COLMAP sparse model (cameras.txt, images.txt, points3D.txt in COLMAP's text format: "
                 "keyframes as images with their features, points with their tracks, coloured from the images), "
                 "each image named by its file under --images, so that COLMAP or OpenMVS can densify the survey: "
                 "colmap image_undistorter --image_path IMAGES --input_path DIR --output_path DENSE. Beside it, "
                 "database.db: the same cameras, images and features as a COLMAP project, with the map's matches "
                 "between every two keyframes that see points in common, so that COLMAP goes on from them without "
                 "extracting or matching again: colmap mapper --database_path DIR/database.db --image_path IMAGES "
                 "--output_path SPARSE (no descriptors: stitch's ORB ones are not the SIFT ones COLMAP's matchers "
                 "read).");
  args.AddPositional(&positional, "colmap RUN_DIR", "what to export (colmap) and the run folder", 2);
  args.AddOption("--images", &images, "PATH",
                 "the flight's images: the dataset the run played (default: the run's --dataset)");
  args.AddOption("--out", &out, "DIR", "where to write the model (created; must not hold one already)");
  if (!args.Parse(argc, argv)) return args.exit_code();
  try {
    if (positional.size() != 2 || positional[0] != "colmap") {
      throw Error("give what to export and the run folder: stitch export colmap RUN_DIR --out DIR");
    }
    if (out.empty()) throw Error("give --out DIR");
    const std::string run_dir = positional[1];
    const RunInfo info = LoadRunInfo(run_dir);
    const fs::path model_dir = fs::path(run_dir) / "colmap";
    if (!fs::exists(model_dir / "images.txt")) {
      throw Error(run_dir +
                  " has no colmap/ model (the merger writes one when it stops; a run of an older stitch, "
                  "or one whose merger wrote nothing)");
    }
    if (images.empty()) images = info.dataset;
    if (images.empty()) {
      throw Error(
          "the run played the synthetic flight, which has no image files: write them with `stitch render "
          "--out DIR` (the same settings) and give --images DIR");
    }
    if (fs::exists(fs::path(out) / "images.txt") || fs::exists(fs::path(out) / "database.db")) {
      throw Error(out + " already holds a model; give a new --out");
    }
    fs::create_directories(out);
    ColmapModel model = ReadColmapModel(model_dir.string());
    model = ModelOnImages(std::move(model), images, info.start_frame, (fs::path(out) / ".camera.yaml").string());
    fs::remove(fs::path(out) / ".camera.yaml");
    WriteColmapModel(model, out);
    const ColmapDatabaseSummary database = WriteColmapDatabase(model, (fs::path(out) / "database.db").string());
    std::printf("wrote %zu images and %zu points (reprojection %.2f px rms) to %s, on the images of %s\n",
                model.images.size(), model.points.size(), ReprojectionRms(model), out.c_str(), images.c_str());
    std::printf("and database.db: %d keypoints, %d matches between %d pairs of images\n", database.keypoints,
                database.matches, database.image_pairs);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch export: %s\n", e.what());
    return 1;
  }
}

}  // namespace stitch
