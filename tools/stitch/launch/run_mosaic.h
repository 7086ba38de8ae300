#pragma once
// A run's orthomosaic (orthomosaic.h) from its folder: the merger's largest map (colmap/: the
// keyframes' poses and cameras, the points that shape the ground), its place on Earth where the
// run placed it (geo/georeference.json: then the mosaic is north up in WGS 84 / UTM, in metres),
// and the keyframes' pictures from what the run played (run_images.h). Written as a GeoTIFF; for
// the synthetic flight also measured against the world's true orthophoto.

#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "stitch/geo/geodetic.h"
#include "stitch/geometry/rigid3.h"
#include "stitch/mosaic/mosaic_options.h"
#include "stitch/source/source.h"

namespace stitch {

// What the run played, as run.json and config.yaml in its folder say (a live camera's run: its
// live_uri set to what it was, whose frames cannot be read again). Throws stitch::Error.
SourceSpec SourceOfRun(const std::string& run_dir);

// The largest map's place on Earth (geo/georeference.json); empty when the run was not placed, or
// its largest map was not. Throws stitch::Error for a file that is not what stitch writes.
struct MapOnEarth {
  GeodeticPoint origin;  // of the local ENU frame
  Sim3d enu_from_map;
};
std::optional<MapOnEarth> LargestMapOnEarth(const std::string& run_dir);

struct RunMosaic {
  std::string path;  // the GeoTIFF
  std::string crs;   // "EPSG:32632 (WGS 84 / UTM zone 32N)", or the local frame's words
  bool on_earth = false;
  double gsd = 0.0;      // metres on Earth, else the map's units
  std::string pictures;  // "the flight's images" or "the pictures the ground received"
  int images = 0;        // pictures laid
  int width = 0, height = 0;
  double area = 0.0;              // covered, square metres on Earth (the map's units squared otherwise)
  double cpu_ms_per_image = 0.0;  // the mosaic's own upkeep (laying an image on it), not reading the image
  // Against the synthetic world's true orthophoto (the synthetic flight only).
  struct Truth {
    int checkpoints = 0;
    double rms_gsd = 0.0;                   // as placed: on Earth with no alignment, else after the trajectory's Sim3
    double rms_after_similarity_gsd = 0.0;  // after the 2D similarity that fits the checkpoints best
    Eigen::Vector2d mean_offset_gsd = Eigen::Vector2d::Zero();  // east, north
    double surveyed_area = 0.0;  // square metres: the planned flight's footprints (gust frames left out)
    double coverage = 0.0;       // of the surveyed area, the share the mosaic covers
  };
  std::optional<Truth> truth;

  nlohmann::json ToJson() const;
  std::vector<std::string> Summary() const;  // lines for the terminal
};

// Which pictures a mosaic is made of: the flight's own images (what the run played: each keyframe
// of colmap/), the reduced pictures the ground received (keyframe_images/: each frame of the
// largest map that has one, placed by its pose in poses.tsv), or the first of those at hand.
enum class MosaicPictures { kAuto, kSource, kReceived };
// "auto", "source" or "received"; throws stitch::Error otherwise.
MosaicPictures ParseMosaicPictures(const std::string& name);

// Makes the mosaic of the run in `run_dir` (played from `source`) and writes it to `out_path` as a
// GeoTIFF; for the synthetic flight, also each checkpoint with its offset (FILE.checkpoints.csv). Throws stitch::Error:
// no colmap/ model, images that cannot be read, a mosaic larger than options.max_pixels, a file that cannot be written.
RunMosaic MakeRunMosaic(const std::string& run_dir, const SourceSpec& source, const MosaicOptions& options,
                        const std::string& out_path, MosaicPictures pictures = MosaicPictures::kAuto);

}  // namespace stitch
