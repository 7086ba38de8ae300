// stitch export colmap: a run's merged map as a COLMAP sparse model on the flight's images.

#include <cstdio>
#include <filesystem>
#include <map>
#include <regex>

#include <opencv2/imgcodecs.hpp>

#include "stitch/io/calibration.h"
#include "stitch/io/colmap_database.h"
#include "stitch/io/colmap_model.h"
#include "stitch/io/image_sequence.h"
#include "stitch/records/run_info.h"
#include "stitch/util/args.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "tools/stitch/commands.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

// The run's model (RUN/colmap, named agentA-frameNNNNNN) with each image named by its file
// relative to `images` and each point coloured from the first image that sees it.
ColmapModel OnTheImages(ColmapModel model, const std::string& images, int start_frame, const std::string& scratch) {
  // The dataset's own reader lists its images in play order; the model's camera stands in for a
  // calibration (the run's; its size is checked against the images below), which an image folder may not have.
  if (model.cameras.size() != 1) {
    throw Error("the map holds the images of " + std::to_string(model.cameras.size()) +
                " cameras; --images names one aircraft's images (export a single aircraft's run)");
  }
  const int camera_id = model.cameras.begin()->first;
  const Camera camera = model.cameras.begin()->second;
  SaveCalibration(camera, scratch);
  SequenceOptions options;
  options.calibration_path = scratch;
  options.start_frame = start_frame;
  const auto sequence = OpenDataset(images, options);
  const std::regex placeholder("agent([0-9]+)-frame([0-9]+)");
  std::map<int, std::vector<std::pair<int, int>>> first_sight;  // image index -> (feature, point index)
  for (size_t p = 0; p < model.points.size(); ++p) {
    const auto& [image_id, feature] = model.points[p].track.front();
    first_sight[image_id].push_back({feature, static_cast<int>(p)});
  }
  std::vector<std::string> paths;  // per model image
  for (ColmapImage& image : model.images) {
    std::smatch match;
    if (!std::regex_match(image.name, match, placeholder)) {
      throw Error("image " + std::to_string(image.id) + " is named '" + image.name +
                  "', not agentA-frameNNNNNN as the merger names them");
    }
    if (std::stoi(match[1]) != 0) {
      throw Error("the map holds keyframes of aircraft " + match[1].str() +
                  "; --images names one aircraft's images (export a single aircraft's run)");
    }
    const int frame = std::stoi(match[2]);
    const std::string path = sequence->image_path(frame);
    if (path.empty()) {
      throw Error(images + " has no image file for frame " + std::to_string(frame) +
                  (sequence->size() <= frame ? " (it holds " + std::to_string(sequence->size()) + " frames)"
                                             : std::string(" (a video: write its frames as images first)")));
    }
    image.name = fs::relative(path, images).generic_string();
    paths.push_back(path);
  }
  // A run works at a reduced size where the camera's frames are larger (ingest.max_working_pixels):
  // the model goes back to the images' size.
  for (const std::string& path : paths) {
    const cv::Mat first = cv::imread(path, cv::IMREAD_GRAYSCALE);
    if (first.empty()) continue;
    if (first.cols != camera.width() || first.rows != camera.height()) {
      STITCH_LOG(INFO) << "the run worked at " << camera.width() << "x" << camera.height()
                       << "; the model is scaled to the images' " << first.cols << "x" << first.rows;
      model = ResizeColmapModel(std::move(model), camera_id, first.cols, first.rows);
    }
    break;
  }
  for (size_t i = 0; i < model.images.size(); ++i) {
    const ColmapImage& image = model.images[i];
    const auto sights = first_sight.find(image.id);
    if (sights == first_sight.end()) continue;
    const cv::Mat colour = cv::imread(paths[i], cv::IMREAD_COLOR);
    if (colour.empty()) continue;  // grey stays
    for (const auto& [feature, p] : sights->second) {
      const Eigen::Vector2d& f = image.features[feature];
      const int x = std::clamp(static_cast<int>(std::lround(f.x())), 0, colour.cols - 1);
      const int y = std::clamp(static_cast<int>(std::lround(f.y())), 0, colour.rows - 1);
      const cv::Vec3b bgr = colour.at<cv::Vec3b>(y, x);
      model.points[p].rgb = {bgr[2], bgr[1], bgr[0]};
    }
  }
  return model;
}

}  // namespace

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
    model = OnTheImages(std::move(model), images, info.start_frame, (fs::path(out) / ".camera.yaml").string());
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
