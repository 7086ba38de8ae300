#include "stitch/mosaic/orthomosaic.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <set>

#include <opencv2/imgcodecs.hpp>

#include "stitch/util/error.h"
#include "stitch/util/options.h"
#include "stitch/util/statistics.h"

namespace stitch {
namespace {

constexpr float kNotDrawn = std::numeric_limits<float>::infinity();
constexpr int kJpegQuality = 95;  // what a redraw reads back

Eigen::Vector3d CentreOf(const Sim3d& cam_from_ground) {
  return cam_from_ground.Inverse().translation;
}

// Bilinear, BGR from a CV_8UC1 or CV_8UC3 image; (x, y) inside [0, cols - 1] x [0, rows - 1].
cv::Vec3b Sample(const cv::Mat& image, double x, double y) {
  const int x0 = std::min(static_cast<int>(x), image.cols - 2), y0 = std::min(static_cast<int>(y), image.rows - 2);
  const double fx = x - x0, fy = y - y0;
  const double w00 = (1 - fx) * (1 - fy), w01 = fx * (1 - fy), w10 = (1 - fx) * fy, w11 = fx * fy;
  if (image.channels() == 1) {
    const uchar* r0 = image.ptr<uchar>(y0) + x0;
    const uchar* r1 = image.ptr<uchar>(y0 + 1) + x0;
    const auto v = static_cast<uchar>(std::lround(w00 * r0[0] + w01 * r0[1] + w10 * r1[0] + w11 * r1[1]));
    return {v, v, v};
  }
  const cv::Vec3b* r0 = image.ptr<cv::Vec3b>(y0) + x0;
  const cv::Vec3b* r1 = image.ptr<cv::Vec3b>(y0 + 1) + x0;
  cv::Vec3b out;
  for (int k = 0; k < 3; ++k) {
    out[k] = static_cast<uchar>(std::lround(w00 * r0[0][k] + w01 * r0[1][k] + w10 * r1[0][k] + w11 * r1[1][k]));
  }
  return out;
}

}  // namespace

Eigen::Vector3d WithinOffNadirCone(const Eigen::Vector3d& ray, double max_angle) {
  const double horizontal = ray.head<2>().norm();
  if (horizontal < 1e-12 || std::atan2(horizontal, -ray.z()) <= max_angle) return ray;
  return Eigen::Vector3d(ray.x() / horizontal * std::sin(max_angle), ray.y() / horizontal * std::sin(max_angle),
                         -std::cos(max_angle));
}

std::optional<double> NadirGsd(const Camera& camera, const Sim3d& cam_from_ground, const GroundSurface& surface) {
  const Eigen::Vector3d centre = CentreOf(cam_from_ground);
  const double height = centre.z() - surface.Height(centre.x(), centre.y());
  if (!(height > 0) || !std::isfinite(height)) return std::nullopt;
  return height / std::sqrt(camera.fx() * camera.fy());
}

std::optional<double> MedianNadirGsd(const std::vector<MosaicView>& views,
                                     const std::vector<Eigen::Vector3d>& ground_points) {
  std::vector<double> heights;
  for (const Eigen::Vector3d& p : ground_points) heights.push_back(p.z());
  const GroundSurface flat(Median(heights));
  std::vector<double> gsds;
  for (const MosaicView& view : views) {
    if (const auto gsd = NadirGsd(*view.camera, view.cam_from_ground, flat)) gsds.push_back(*gsd);
  }
  if (gsds.empty()) return std::nullopt;
  return Median(gsds);
}

Orthomosaic::Orthomosaic(const MosaicOptions& options, const MosaicGrid& grid, GroundSurface surface)
    : options_(options), grid_(grid), surface_(std::move(surface)) {
  CheckOptions(options_, "mosaic");
  if (!(grid_.gsd > 0) || !std::isfinite(grid_.gsd) || !grid_.origin.allFinite()) {
    throw Error("the mosaic's grid needs a positive ground sample distance and a finite origin");
  }
}

std::optional<cv::Rect> Orthomosaic::Footprint(const Image& image) const {
  // The rays of the image's edge, each held within the off-nadir cone, meet the lowest and the
  // highest ground: the footprint lies within their bounds.
  const Eigen::Quaterniond ground_from_cam = image.cam_from_ground.rotation.conjugate();
  const double max_angle = options_.max_off_nadir_deg * M_PI / 180.0;
  const Camera& camera = image.camera;
  const double w = camera.width() - 1, h = camera.height() - 1;
  std::vector<Eigen::Vector2d> edge;
  const int steps = 16;
  for (int i = 0; i <= steps; ++i) {
    const double f = static_cast<double>(i) / steps;
    edge.insert(edge.end(), {{f * w, 0}, {f * w, h}, {0, f * h}, {w, f * h}});
  }
  Eigen::Vector2d lo = Eigen::Vector2d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  bool any = false;
  for (const Eigen::Vector2d& pixel : edge) {
    const Eigen::Vector3d ray = WithinOffNadirCone(ground_from_cam * camera.PixelToRay(pixel), max_angle);
    if (ray.z() >= 0) continue;
    for (const double ground : {surface_.min_height(), surface_.max_height()}) {
      if (image.centre.z() <= ground) continue;
      const Eigen::Vector2d hit = (image.centre + ray * ((ground - image.centre.z()) / ray.z())).head<2>();
      lo = lo.cwiseMin(hit);
      hi = hi.cwiseMax(hit);
      any = true;
    }
  }
  if (!any) return std::nullopt;
  // Ground x grows with columns, y falls with rows.
  const Eigen::Vector2d a = grid_.Pixel({lo.x(), hi.y()}), b = grid_.Pixel({hi.x(), lo.y()});
  const double limit = 1e8;
  if (!(a.cwiseAbs().maxCoeff() < limit && b.cwiseAbs().maxCoeff() < limit)) return std::nullopt;
  const int col0 = static_cast<int>(std::floor(a.x())), row0 = static_cast<int>(std::floor(a.y()));
  const int col1 = static_cast<int>(std::ceil(b.x())), row1 = static_cast<int>(std::ceil(b.y()));
  if (static_cast<double>(col1 - col0 + 1) * (row1 - row0 + 1) > options_.max_pixels) return std::nullopt;
  return cv::Rect(col0, row0, col1 - col0 + 1, row1 - row0 + 1);
}

std::vector<Orthomosaic::TileKey> Orthomosaic::TilesOf(const cv::Rect& pixels) const {
  const auto tile_of = [&](int p) { return static_cast<int>(std::floor(static_cast<double>(p) / options_.tile_px)); };
  std::vector<TileKey> keys;
  for (int j = tile_of(pixels.y); j <= tile_of(pixels.y + pixels.height - 1); ++j) {
    for (int i = tile_of(pixels.x); i <= tile_of(pixels.x + pixels.width - 1); ++i) keys.push_back({i, j});
  }
  return keys;
}

int64_t Orthomosaic::Draw(int id, const Image& image, const cv::Mat& pixels, const TileKey& key, TileBuffers* tile,
                          const cv::Mat& heights) const {
  const int n = options_.tile_px;
  const cv::Rect tile_rect(key.first * n, key.second * n, n, n);
  const cv::Rect area = tile_rect & *image.pixels;
  if (area.empty()) return 0;
  const double max_tan = std::tan(options_.max_off_nadir_deg * M_PI / 180.0);
  const double max_score = max_tan * max_tan;
  const Camera& camera = image.camera;
  // The image's pixels may be at another size than its camera's (a reduced copy).
  const double sx = static_cast<double>(pixels.cols) / camera.width();
  const double sy = static_cast<double>(pixels.rows) / camera.height();
  const double border = options_.image_border_px;
  const Eigen::Matrix3d rotation = image.cam_from_ground.scale * image.cam_from_ground.rotation.toRotationMatrix();
  const Eigen::Vector3d& translation = image.cam_from_ground.translation;
  int64_t taken = 0;
  for (int row = area.y; row < area.y + area.height; ++row) {
    const int r = row - tile_rect.y;
    float* score = tile->score.ptr<float>(r);
    int32_t* owner = tile->owner.ptr<int32_t>(r);
    cv::Vec3b* colour = tile->colour.ptr<cv::Vec3b>(r);
    const double* height = heights.empty() ? nullptr : heights.ptr<double>(r);
    for (int col = area.x; col < area.x + area.width; ++col) {
      const int c = col - tile_rect.x;
      const Eigen::Vector2d g = grid_.Ground(col, row);
      const Eigen::Vector3d ground(g.x(), g.y(), height ? height[c] : surface_.Height(g.x(), g.y()));
      const Eigen::Vector3d d = ground - image.centre;
      if (d.z() >= 0) continue;
      const auto s = static_cast<float>(d.head<2>().squaredNorm() / (d.z() * d.z()));
      if (s > max_score || s > score[c] || (s == score[c] && id > owner[c])) continue;
      const std::optional<Eigen::Vector2d> p = camera.Project(rotation * ground + translation);
      if (!p || !camera.InImage(*p, border)) continue;
      const double x = std::clamp((p->x() + 0.5) * sx - 0.5, 0.0, pixels.cols - 1.0);
      const double y = std::clamp((p->y() + 0.5) * sy - 0.5, 0.0, pixels.rows - 1.0);
      colour[c] = Sample(pixels, x, y);
      score[c] = s;
      if (owner[c] != id) ++taken;
      owner[c] = id;
    }
  }
  return taken;
}

Orthomosaic::Change Orthomosaic::SetImage(int id, const Camera& camera, const Sim3d& cam_from_ground,
                                          const cv::Mat& image) {
  if (image.empty() || image.depth() != CV_8U || (image.channels() != 1 && image.channels() != 3)) {
    throw Error("a mosaic image must be 8-bit grey or BGR");
  }
  if (image.cols < 2 || image.rows < 2) throw Error("a mosaic image must be at least 2x2 pixels");
  std::vector<uchar> jpeg;
  if (!cv::imencode(".jpg", image, jpeg, {cv::IMWRITE_JPEG_QUALITY, kJpegQuality})) {
    throw Error("a mosaic image could not be compressed");
  }
  return SetCompressedImage(id, camera, cam_from_ground, std::move(jpeg));
}

Orthomosaic::Change Orthomosaic::SetCompressedImage(int id, const Camera& camera, const Sim3d& cam_from_ground,
                                                    std::vector<uchar> jpeg) {
  cv::Mat decoded;
  try {
    decoded = cv::imdecode(jpeg, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception&) {
    decoded.release();
  }
  if (decoded.empty() || decoded.depth() != CV_8U || (decoded.channels() != 1 && decoded.channels() != 3) ||
      decoded.cols < 2 || decoded.rows < 2) {
    throw Error("a mosaic image's JPEG does not decode to an 8-bit grey or BGR image of at least 2x2 pixels");
  }
  Image entry;
  entry.camera = camera;
  entry.cam_from_ground = cam_from_ground;
  entry.centre = CentreOf(cam_from_ground);
  entry.jpeg = std::move(jpeg);
  entry.pixels = entry.centre.allFinite() ? Footprint(entry) : std::nullopt;
  Change change;
  const auto existing = images_.find(id);
  if (existing != images_.end()) {
    // Moved, or new pixels: every tile it covered or covers is drawn again.
    std::set<TileKey> keys;
    if (existing->second.pixels) {
      for (const TileKey& key : TilesOf(*existing->second.pixels)) keys.insert(key);
    }
    if (entry.pixels) {
      for (const TileKey& key : TilesOf(*entry.pixels)) keys.insert(key);
    }
    existing->second = std::move(entry);
    RedrawAll({keys.begin(), keys.end()}, &change);
    return change;
  }
  const Image& added = images_.emplace(id, std::move(entry)).first->second;
  if (!added.pixels) return change;
  for (const TileKey& key : TilesOf(*added.pixels)) {
    auto tile = tiles_.find(key);
    const bool fresh = tile == tiles_.end();
    if (fresh) {
      const int n = options_.tile_px;
      tile = tiles_
                 .emplace(key, TileBuffers{cv::Mat(n, n, CV_8UC3, cv::Scalar::all(0)), cv::Mat(n, n, CV_32F, kNotDrawn),
                                           cv::Mat(n, n, CV_32S, cv::Scalar(-1))})
                 .first;
    }
    const int64_t taken = Draw(id, added, decoded, key, &tile->second);
    if (taken == 0 && fresh) {
      tiles_.erase(tile);  // nothing of it there after all
      continue;
    }
    if (taken > 0) changed_.insert(key);
    ++change.tiles;
    change.pixels += taken;
  }
  return change;
}

bool Orthomosaic::MoveImage(int id, const Sim3d& cam_from_ground, Change* change) {
  return MoveImages({{id, cam_from_ground}}, change) == 1;
}

int Orthomosaic::MoveImages(const std::vector<std::pair<int, Sim3d>>& moves, Change* change) {
  std::set<TileKey> keys;
  int moved = 0;
  for (const auto& [id, cam_from_ground] : moves) {
    const auto it = images_.find(id);
    if (it == images_.end()) continue;
    ++moved;
    if (it->second.pixels) {
      for (const TileKey& key : TilesOf(*it->second.pixels)) keys.insert(key);
    }
    it->second.cam_from_ground = cam_from_ground;
    it->second.centre = CentreOf(cam_from_ground);
    it->second.pixels = it->second.centre.allFinite() ? Footprint(it->second) : std::nullopt;
    if (it->second.pixels) {
      for (const TileKey& key : TilesOf(*it->second.pixels)) keys.insert(key);
    }
  }
  Change redrawn;
  if (moved > 0) RedrawAll({keys.begin(), keys.end()}, &redrawn);
  if (change) *change = redrawn;
  return moved;
}

bool Orthomosaic::RemoveImage(int id, Change* change) {
  const auto it = images_.find(id);
  if (it == images_.end()) return false;
  const std::optional<cv::Rect> pixels = it->second.pixels;
  images_.erase(it);
  Change redrawn;
  if (pixels) RedrawAll(TilesOf(*pixels), &redrawn);
  if (change) *change = redrawn;
  return true;
}

void Orthomosaic::RedrawAll(const std::vector<TileKey>& keys, Change* change) {
  // Each image over these tiles is decoded once.
  const int n = options_.tile_px;
  std::map<int, cv::Mat> decoded;
  for (const TileKey& key : keys) {
    const cv::Rect tile_rect(key.first * n, key.second * n, n, n);
    TileBuffers tile{cv::Mat(n, n, CV_8UC3, cv::Scalar::all(0)), cv::Mat(n, n, CV_32F, kNotDrawn),
                     cv::Mat(n, n, CV_32S, cv::Scalar(-1))};
    // The ground under the tile, looked up once for all the images drawn into it.
    cv::Mat heights(n, n, CV_64F);
    for (int r = 0; r < n; ++r) {
      double* height = heights.ptr<double>(r);
      for (int c = 0; c < n; ++c) {
        const Eigen::Vector2d g = grid_.Ground(tile_rect.x + c, tile_rect.y + r);
        height[c] = surface_.Height(g.x(), g.y());
      }
    }
    int64_t drawn = 0;
    for (const auto& [id, image] : images_) {
      if (!image.pixels || (tile_rect & *image.pixels).empty()) continue;
      auto pixels = decoded.find(id);
      if (pixels == decoded.end()) pixels = decoded.emplace(id, cv::imdecode(image.jpeg, cv::IMREAD_UNCHANGED)).first;
      drawn += Draw(id, image, pixels->second, key, &tile, heights);
    }
    ++change->tiles;
    changed_.insert(key);
    if (drawn == 0) {
      tiles_.erase(key);
    } else {
      tiles_[key] = std::move(tile);
    }
  }
  // The pixels each image gives are not told apart after a redraw: count the moved image's tiles.
  change->pixels = 0;
  for (const TileKey& key : keys) {
    const auto tile = tiles_.find(key);
    if (tile != tiles_.end()) change->pixels += cv::countNonZero(tile->second.owner >= 0);
  }
}

std::vector<std::pair<int, int>> Orthomosaic::TakeChangedTiles() {
  std::vector<std::pair<int, int>> keys(changed_.begin(), changed_.end());
  changed_.clear();
  return keys;
}

std::vector<std::pair<int, int>> Orthomosaic::TileKeys() const {
  std::vector<std::pair<int, int>> keys;
  keys.reserve(tiles_.size());
  for (const auto& entry : tiles_) keys.push_back(entry.first);
  return keys;
}

MosaicRaster Orthomosaic::Tile(int tile_col, int tile_row) const {
  MosaicRaster raster;
  const auto tile = tiles_.find({tile_col, tile_row});
  if (tile == tiles_.end()) return raster;
  raster.col0 = tile_col * options_.tile_px;
  raster.row0 = tile_row * options_.tile_px;
  raster.colour = tile->second.colour.clone();
  raster.coverage = tile->second.owner >= 0;
  return raster;
}

int64_t Orthomosaic::covered_pixels() const {
  int64_t covered = 0;
  for (const auto& entry : tiles_) covered += cv::countNonZero(entry.second.owner >= 0);
  return covered;
}

MosaicRaster Orthomosaic::Render() const {
  MosaicRaster raster;
  const int n = options_.tile_px;
  cv::Rect bounds;
  for (const auto& [key, tile] : tiles_) {
    const cv::Rect drawn = cv::boundingRect(tile.owner >= 0);
    if (drawn.empty()) continue;
    const cv::Rect in_grid(drawn.x + key.first * n, drawn.y + key.second * n, drawn.width, drawn.height);
    bounds = bounds.empty() ? in_grid : (bounds | in_grid);
  }
  if (bounds.empty()) return raster;
  if (static_cast<double>(bounds.width) * bounds.height > options_.max_pixels) {
    throw Error("the mosaic spans " + std::to_string(bounds.width) + " x " + std::to_string(bounds.height) +
                " pixels, more than mosaic.max_pixels (" + std::to_string(options_.max_pixels) +
                "): a larger gsd_m, or a map without cameras far from the rest");
  }
  raster.col0 = bounds.x;
  raster.row0 = bounds.y;
  raster.colour = cv::Mat(bounds.height, bounds.width, CV_8UC3, cv::Scalar::all(0));
  raster.coverage = cv::Mat(bounds.height, bounds.width, CV_8UC1, cv::Scalar(0));
  for (const auto& [key, tile] : tiles_) {
    const cv::Rect tile_rect(key.first * n, key.second * n, n, n);
    const cv::Rect part = tile_rect & bounds;
    if (part.empty()) continue;
    const cv::Rect from(part.x - tile_rect.x, part.y - tile_rect.y, part.width, part.height);
    const cv::Rect to(part.x - bounds.x, part.y - bounds.y, part.width, part.height);
    tile.colour(from).copyTo(raster.colour(to));
    cv::Mat drawn = tile.owner(from) >= 0;
    drawn.copyTo(raster.coverage(to));
  }
  return raster;
}

}  // namespace stitch
