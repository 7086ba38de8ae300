#include "stitch/mosaic/live_mosaic.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "stitch/util/error.h"
#include "stitch/util/time.h"

namespace stitch {
namespace {

// Points a map needs before its ground is shaped.
constexpr size_t kMinPoints = 50;

}  // namespace

Sim3d GroundFromMapByPlane(const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector3d>& centres) {
  if (points.size() < 3) throw Error("a ground plane needs at least 3 points");
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (const Eigen::Vector3d& p : points) scatter += (p - mean) * (p - mean).transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(scatter);
  Eigen::Vector3d normal = solver.eigenvectors().col(0);
  const Eigen::Vector3d along = solver.eigenvectors().col(2);
  double above = 0;
  for (const Eigen::Vector3d& c : centres) above += normal.dot(c - mean);
  if (above < 0) normal = -normal;
  Eigen::Matrix3d rotation;
  rotation.row(0) = along;
  rotation.row(1) = normal.cross(along);
  rotation.row(2) = normal;
  const Eigen::Quaterniond q(rotation);
  return Sim3d(1.0, q, -(q * mean));
}

double ReliefOverHeight(const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector3d>& centres) {
  if (centres.empty()) throw Error("a map's relief needs a camera");
  const Sim3d ground_from_map = GroundFromMapByPlane(points, centres);
  double squared_relief = 0;
  for (const Eigen::Vector3d& p : points) {
    const double z = (ground_from_map * p).z();
    squared_relief += z * z;
  }
  std::vector<double> heights;
  for (const Eigen::Vector3d& c : centres) heights.push_back((ground_from_map * c).z());
  std::nth_element(heights.begin(), heights.begin() + heights.size() / 2, heights.end());
  const double height = heights[heights.size() / 2];
  const double relief = std::sqrt(squared_relief / points.size());
  return height > 0 ? relief / height : std::numeric_limits<double>::infinity();
}

std::string WhyNotAGroundSeenFromAbove(const std::vector<Eigen::Vector3d>& points,
                                       const std::vector<Eigen::Vector3d>& centres, const MosaicOptions& options) {
  if (options.live_max_relief <= 0) return "";
  const double relief = ReliefOverHeight(points, centres);
  if (relief <= options.live_max_relief) return "";
  char text[200];
  std::snprintf(text, sizeof(text),
                "its points lie %.2f of its cameras' height from their plane (merger.mosaic.live_max_relief %.2f)",
                relief, options.live_max_relief);
  return text;
}

LiveMosaic::LiveMosaic(const MosaicOptions& options) : options_(options) {}

void LiveMosaic::AddPicture(int key, const Camera& camera, std::vector<uint8_t> jpeg) {
  pictures_[key] = Picture{camera, std::move(jpeg)};
}

Sim3d LiveMosaic::CamFromGround(const Rigid3d& world_from_cam) const {
  const Rigid3d cam_from_world = world_from_cam.Inverse();
  return Sim3d(1.0, cam_from_world.rotation, cam_from_world.translation) * ground_from_map_.Inverse();
}

bool LiveMosaic::Restart(const MapState& state) {
  std::vector<Eigen::Vector3d> centres;
  for (const auto& [key, pose] : state.world_from_cam) {
    if (pictures_.count(key)) centres.push_back(pose.translation);
  }
  if (state.points.size() < kMinPoints || centres.size() < static_cast<size_t>(options_.live_min_pictures)) {
    waiting_for_ = "a map of " + std::to_string(kMinPoints) + " points placing " +
                   std::to_string(options_.live_min_pictures) + " pictures";
    return false;
  }
  // A ground seen from above: the points lie near their plane against the cameras' height.
  if (const std::string why = WhyNotAGroundSeenFromAbove(state.points, centres, options_); !why.empty()) {
    waiting_for_ = "a ground seen from above: " + why;
    return false;
  }
  const Sim3d ground_from_map = state.on_earth ? Sim3d() : GroundFromMapByPlane(state.points, centres);
  std::vector<Eigen::Vector3d> ground_points;
  for (const Eigen::Vector3d& p : state.points) ground_points.push_back(ground_from_map * p);
  MosaicGrid grid;
  grid.gsd = options_.gsd_m;
  if (grid.gsd == 0) {
    std::vector<MosaicView> views;
    for (const auto& [key, pose] : state.world_from_cam) {
      const auto picture = pictures_.find(key);
      if (picture == pictures_.end()) continue;
      const Rigid3d cam_from_world = pose.Inverse();
      views.push_back({&picture->second.camera,
                       Sim3d(1.0, cam_from_world.rotation, cam_from_world.translation) * ground_from_map.Inverse()});
    }
    const std::optional<double> gsd = MedianNadirGsd(views, ground_points);
    if (!gsd) {
      waiting_for_ = "a camera above the ground";
      return false;
    }
    grid.gsd = *gsd;
  }
  mosaic_.emplace(options_, grid,
                  GroundSurface::FromPoints(ground_points, options_.surface_cell_gsd * grid.gsd,
                                            std::min<int>(options_.surface_min_points, ground_points.size())));
  ground_from_map_ = ground_from_map;
  frame_ = state.frame;
  ++revision_;
  shaped_by_points_ = state.points.size();
  waiting_for_.clear();
  laid_.clear();
  return true;
}

LiveMosaic::Change LiveMosaic::Update(const MapState& state) {
  const double started = ThreadCpuMs();
  Change change;
  if (!mosaic_ || state.frame != frame_ || state.points.size() >= 2 * shaped_by_points_) {
    if (!Restart(state)) {
      if (mosaic_) {  // what was drawn lies on a map that is not (or no longer) a ground to draw
        withdrawn_grid_ = mosaic_->grid();
        mosaic_.reset();
        laid_.clear();
        ++revision_;
        change.withdrawn = true;
      }
      change.cpu_ms = ThreadCpuMs() - started;
      return change;
    }
    withdrawn_grid_.reset();
    change.redrawn = true;
  }
  const double gsd = mosaic_->grid().gsd;
  // Pictures whose frame the map no longer places (a submap that left it) come out.
  for (auto it = laid_.begin(); it != laid_.end();) {
    if (state.world_from_cam.count(it->first)) {
      ++it;
      continue;
    }
    Orthomosaic::Change removed;
    mosaic_->RemoveImage(it->first, &removed);
    change.tiles += removed.tiles;
    it = laid_.erase(it);
  }
  std::vector<std::pair<int, Sim3d>> moves;
  for (const auto& [key, pose] : state.world_from_cam) {
    const auto picture = pictures_.find(key);
    if (picture == pictures_.end()) continue;
    const auto laid = laid_.find(key);
    if (laid == laid_.end()) {
      const Orthomosaic::Change added =
          mosaic_->SetCompressedImage(key, picture->second.camera, CamFromGround(pose), picture->second.jpeg);
      laid_[key] = pose;
      ++change.laid;
      change.tiles += added.tiles;
      continue;
    }
    // Moved by more than half a mosaic pixel where it sees the ground: its centre, or its view
    // turned by that much at its height above the ground.
    const Eigen::Vector3d centre = ground_from_map_ * pose.translation;
    const double height = std::max(gsd, centre.z() - mosaic_->surface().Height(centre.x(), centre.y()));
    const double shifted = (pose.translation - laid->second.translation).norm();
    const double turned = Eigen::AngleAxisd(laid->second.rotation.conjugate() * pose.rotation).angle() * height;
    if (std::max(shifted, turned) <= 0.5 * gsd) continue;
    moves.emplace_back(key, CamFromGround(pose));
    laid->second = pose;
  }
  // A map refined moves most of its pictures: their tiles are drawn again once, not once each.
  Orthomosaic::Change moved;
  change.moved += mosaic_->MoveImages(moves, &moved);
  change.tiles += moved.tiles;
  change.cpu_ms = ThreadCpuMs() - started;
  return change;
}

std::vector<LiveMosaicTile> LiveMosaic::TakeChangedTiles() {
  std::vector<LiveMosaicTile> tiles;
  if (withdrawn_grid_) {
    LiveMosaicTile cleared;
    cleared.revision = revision_;
    cleared.frame = frame_;
    cleared.ground_from_map = ground_from_map_;
    cleared.grid = *withdrawn_grid_;
    cleared.tile_px = options_.tile_px;
    cleared.version = ++tile_version_;
    tiles.push_back(std::move(cleared));
    withdrawn_grid_.reset();
  }
  if (!mosaic_) return tiles;
  for (const auto& [col, row] : mosaic_->TakeChangedTiles()) {
    LiveMosaicTile tile;
    tile.revision = revision_;
    tile.frame = frame_;
    tile.ground_from_map = ground_from_map_;
    tile.grid = mosaic_->grid();
    tile.tile_px = options_.tile_px;
    tile.col = col;
    tile.row = row;
    tile.version = ++tile_version_;
    const MosaicRaster raster = mosaic_->Tile(col, row);
    if (!raster.colour.empty()) {
      std::vector<cv::Mat> channels;
      cv::split(raster.colour, channels);
      channels.push_back(raster.coverage);
      cv::Mat bgra;
      cv::merge(channels, bgra);
      if (!cv::imencode(".png", bgra, tile.png, {cv::IMWRITE_PNG_COMPRESSION, 1})) {
        throw Error("a mosaic tile could not be encoded as PNG");
      }
    }
    tiles.push_back(std::move(tile));
  }
  return tiles;
}

}  // namespace stitch
