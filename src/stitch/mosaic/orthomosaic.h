#pragma once
// An orthomosaic built image by image: each image laid on the ground surface (ground_surface.h)
// and each mosaic pixel taken from the image that sees it nearest its nadir (the seams run where
// two images are equally steep above the ground, so buildings lean least). The mosaic is tiles
// on an unbounded grid, north up: an image adds only its own footprint, and an image moved (an
// adjustment, a merge) or removed redraws the tiles it covered and covers, from every image over
// them. Images are kept JPEG-compressed for those redraws.
//
// The mosaic's frame ("ground"): x east (or the map's first horizontal axis), y north, z up; in
// metres for a map placed on Earth. One owner thread; not thread-safe.

#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "stitch/geometry/camera.h"
#include "stitch/geometry/rigid3.h"
#include "stitch/mosaic/ground_surface.h"
#include "stitch/mosaic/mosaic_options.h"

namespace stitch {

// Where the mosaic's pixels lie: pixel (col, row) covers ground x in origin.x + [col, col + 1] *
// gsd and y in origin.y - [row, row + 1] * gsd (rows run south). Any integer col and row.
struct MosaicGrid {
  Eigen::Vector2d origin = Eigen::Vector2d::Zero();
  double gsd = 1.0;

  Eigen::Vector2d Ground(double col, double row) const {  // of a pixel's centre
    return {origin.x() + (col + 0.5) * gsd, origin.y() - (row + 0.5) * gsd};
  }
  Eigen::Vector2d Pixel(const Eigen::Vector2d& ground) const {  // continuous, the centre at integers
    return {(ground.x() - origin.x()) / gsd - 0.5, (origin.y() - ground.y()) / gsd - 0.5};
  }
};

// A rectangle of the mosaic: its first pixel in the grid, colour and where it is drawn.
struct MosaicRaster {
  int col0 = 0, row0 = 0;
  cv::Mat colour;    // CV_8UC3, BGR; black where not drawn
  cv::Mat coverage;  // CV_8UC1: 255 where drawn, 0 elsewhere
};

// `ray` (in the ground's frame, z up) turned toward the nadir onto the cone of `max_angle`
// (radians) about it where it points further off; as it is otherwise (and when straight down or up).
Eigen::Vector3d WithinOffNadirCone(const Eigen::Vector3d& ray, double max_angle);

// A mosaic image's camera centre above the ground, over its focal length: the ground sample
// distance it gives at its nadir (in the frame's units). Empty for a camera not above the ground.
std::optional<double> NadirGsd(const Camera& camera, const Sim3d& cam_from_ground, const GroundSurface& surface);

// The pictures' own resolution: the median NadirGsd of the cameras (each with its pose from the
// ground's frame) over a flat ground at the points' median height (`ground_points`, in the
// ground's frame). Empty when no camera is above that ground.
struct MosaicView {
  const Camera* camera = nullptr;
  Sim3d cam_from_ground;
};
std::optional<double> MedianNadirGsd(const std::vector<MosaicView>& views,
                                     const std::vector<Eigen::Vector3d>& ground_points);

class Orthomosaic {
 public:
  // Throws stitch::Error for options that fail their check or a grid without a positive GSD.
  Orthomosaic(const MosaicOptions& options, const MosaicGrid& grid, GroundSurface surface);

  struct Change {
    int tiles = 0;       // tiles drawn into or redrawn
    int64_t pixels = 0;  // mosaic pixels the image now gives
  };
  // Adds image `id` (or moves it, when it is there: its tiles are redrawn): its camera (at the
  // image's size), its pose (any similarity from the ground's frame to the camera's: a map's scale
  // is fine) and its pixels (CV_8UC1 or CV_8UC3). An image not looking at the ground adds nothing.
  Change SetImage(int id, const Camera& camera, const Sim3d& cam_from_ground, const cv::Mat& image);
  // The same from a JPEG (kept as it is: a picture received compressed is not compressed again).
  // Throws stitch::Error for bytes that do not decode to such an image.
  Change SetCompressedImage(int id, const Camera& camera, const Sim3d& cam_from_ground, std::vector<uchar> jpeg);
  // Moves image `id` without new pixels; false when it is not there.
  bool MoveImage(int id, const Sim3d& cam_from_ground, Change* change = nullptr);
  // Moves several images at once, each tile they cover (or covered) drawn again once: what a map
  // refined as a whole needs. Returns how many of them were there (the others are ignored).
  int MoveImages(const std::vector<std::pair<int, Sim3d>>& moves, Change* change = nullptr);
  // Takes image `id` out (its tiles redrawn from the others); false when it is not there.
  bool RemoveImage(int id, Change* change = nullptr);

  // Every drawn pixel, in the smallest rectangle holding them (empty Mats when nothing is drawn).
  MosaicRaster Render() const;
  // The tiles drawn so far, (tile column, tile row): tile (i, j) holds grid pixels
  // [i * tile_px, (i + 1) * tile_px) x [j * tile_px, (j + 1) * tile_px).
  std::vector<std::pair<int, int>> TileKeys() const;
  // One tile's pixels (CV_8UC3 and its coverage); empty Mats for a tile never drawn.
  MosaicRaster Tile(int tile_col, int tile_row) const;
  // The tiles drawn into, redrawn or emptied since the last call (all of them, the first time):
  // what a viewer of the mosaic needs anew.
  std::vector<std::pair<int, int>> TakeChangedTiles();

  int64_t covered_pixels() const;
  const MosaicGrid& grid() const { return grid_; }
  const GroundSurface& surface() const { return surface_; }
  int num_images() const { return static_cast<int>(images_.size()); }

 private:
  struct Image {
    Camera camera;
    Sim3d cam_from_ground;
    Eigen::Vector3d centre;          // the camera's, in the ground's frame
    std::vector<uchar> jpeg;         // its pixels, compressed
    std::optional<cv::Rect> pixels;  // grid pixels its footprint may cover; none when it sees no ground
  };
  struct TileBuffers {
    cv::Mat colour;  // CV_8UC3
    cv::Mat score;   // CV_32F: the tangent squared of the off-nadir angle it was seen at; +inf not drawn
    cv::Mat owner;   // CV_32S: the image it came from, -1 none
  };
  using TileKey = std::pair<int, int>;

  std::optional<cv::Rect> Footprint(const Image& image) const;
  std::vector<TileKey> TilesOf(const cv::Rect& pixels) const;
  // Draws `pixels` (decoded) of image `id` into `tile` where it sees a pixel nearer its nadir than
  // the image there now; returns the pixels it took.
  // `heights`: the ground's height at each of the tile's pixels (CV_64F), or empty to look each up.
  int64_t Draw(int id, const Image& image, const cv::Mat& pixels, const TileKey& key, TileBuffers* tile,
               const cv::Mat& heights = cv::Mat()) const;
  // Clears tile `key` and draws every image over it again.
  void Redraw(const TileKey& key);
  void RedrawAll(const std::vector<TileKey>& keys, Change* change);

  MosaicOptions options_;
  MosaicGrid grid_;
  GroundSurface surface_;
  std::map<int, Image> images_;
  std::map<TileKey, TileBuffers> tiles_;
  std::set<TileKey> changed_;  // since TakeChangedTiles
};

}  // namespace stitch
