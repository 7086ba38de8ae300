#pragma once
// The ground's orthomosaic kept up to date during the flight: the keyframe pictures received,
// each laid where the merged map places its frame now. A picture is laid once; one the map moved
// (an adjustment, a merge) is moved, which redraws only its tiles; a map whose frame changed (its
// root submap: a merge into a larger map) or whose points doubled since the ground was shaped is
// drawn again whole; one whose ground no longer looks like a ground seen from above is withdrawn
// (its tiles cleared). The mosaic's frame is the map's, levelled on its points' best plane, in its
// units; or, for maps the GNSS fixes place, their ENU frame (MapState::on_earth). One owner
// thread; not thread-safe.

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "stitch/geometry/camera.h"
#include "stitch/geometry/rigid3.h"
#include "stitch/mosaic/mosaic_options.h"
#include "stitch/mosaic/orthomosaic.h"

namespace stitch {

// A tile of the live mosaic as a viewer is sent it.
struct LiveMosaicTile {
  int64_t revision = 0;  // LiveMosaic::revision()
  int64_t frame = 0;     // LiveMosaic::frame()
  Sim3d ground_from_map;
  MosaicGrid grid;
  int tile_px = 0;
  int col = 0, row = 0;
  int64_t version = 0;       // higher each time a tile is made
  std::vector<uint8_t> png;  // RGBA, alpha 0 where not drawn; empty: nothing drawn there any more
};

class LiveMosaic {
 public:
  explicit LiveMosaic(const MosaicOptions& options);

  // A picture (a JPEG, kept compressed) of the frame `key` (any number naming it, e.g. agent * 10^7
  // + frame), its camera at the picture's size.
  void AddPicture(int key, const Camera& camera, std::vector<uint8_t> jpeg);

  // The map the pictures are laid on, as the merger holds it now.
  struct MapState {
    int64_t frame = 0;                      // its frame's identity (the root submap): another one redraws all
    std::vector<Eigen::Vector3d> points;    // in its frame
    std::map<int, Rigid3d> world_from_cam;  // the pictured frames it places, by key
    // Its frame is the ENU frame the GNSS fixes place maps in (metres: east, north, up; frame
    // kFrameOnEarth), which is then the mosaic's: north up, each map where its fixes put it.
    bool on_earth = false;
  };
  // MapState::frame of maps on Earth.
  static constexpr int64_t kFrameOnEarth = -1;
  struct Change {
    int laid = 0, moved = 0, tiles = 0;
    bool redrawn = false;    // the whole mosaic drawn again
    bool withdrawn = false;  // the mosaic drawn so far taken back (its map is not what it looked like)
    double cpu_ms = 0.0;     // this update's, the thread's CPU time
  };
  Change Update(const MapState& state);

  // Empty until the map placed enough pictures on a ground of enough points, and after it was
  // withdrawn until it starts again.
  const Orthomosaic* mosaic() const { return mosaic_ ? &*mosaic_ : nullptr; }
  // The mosaic's frame (its ground's) from the map's, as the last start made it (the identity on
  // Earth).
  const Sim3d& ground_from_map() const { return ground_from_map_; }
  int pictures() const { return static_cast<int>(pictures_.size()); }
  int laid() const { return static_cast<int>(laid_.size()); }
  // Higher each time the mosaic started over (its frame, resolution or ground changed): a viewer
  // drops every tile of an older revision.
  int64_t revision() const { return revision_; }
  // The map frame's identity the mosaic lies on (MapState::frame at its start).
  int64_t frame() const { return frame_; }
  // What the last (re)start of the mosaic waited for (a map of enough points, a camera above the
  // ground, a ground seen from above); empty after a start.
  const std::string& waiting_for() const { return waiting_for_; }
  // The tiles drawn anew since the last call, of revision(), as PNG; empty before the mosaic starts.
  // After a withdrawal, one empty tile of the new revision (a viewer clears the older one's).
  std::vector<LiveMosaicTile> TakeChangedTiles();

 private:
  struct Picture {
    Camera camera;
    std::vector<uint8_t> jpeg;
  };
  // Starts over on `state`: the ground's frame, resolution and surface from its points.
  bool Restart(const MapState& state);
  Sim3d CamFromGround(const Rigid3d& world_from_cam) const;

  MosaicOptions options_;
  std::map<int, Picture> pictures_;
  std::optional<Orthomosaic> mosaic_;
  std::optional<MosaicGrid> withdrawn_grid_;  // the withdrawn mosaic's, until its clearing tile is taken
  int64_t frame_ = 0;
  int64_t revision_ = 0;
  int64_t tile_version_ = 0;
  size_t shaped_by_points_ = 0;
  Sim3d ground_from_map_;
  std::string waiting_for_;
  std::map<int, Rigid3d> laid_;  // where each picture was laid, world_from_cam
};

// The map's frame levelled on `points`' best plane: z along its normal toward `centres` (the
// cameras' side), x along the points' widest spread; the map's units. Throws stitch::Error for
// fewer than 3 points.
Sim3d GroundFromMapByPlane(const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector3d>& centres);

// A map's relief against its cameras' height: its points' RMS distance from their best plane
// (GroundFromMapByPlane) over the cameras' median height above it; infinity where they are not
// above it. Small for a ground seen from above (the default flight 0.07), large for a room or a
// street (TUM fr1/rpy 0.34-8.5): MosaicOptions::live_max_relief. Throws stitch::Error for fewer than 3
// points or no camera.
double ReliefOverHeight(const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector3d>& centres);
// Why such a map is not a ground seen from above under `options` (its relief over
// live_max_relief), in words: "its points lie 0.84 of its cameras' height from their plane
// (merger.mosaic.live_max_relief 0.25)"; empty where it is one, or without a limit.
std::string WhyNotAGroundSeenFromAbove(const std::vector<Eigen::Vector3d>& points,
                                       const std::vector<Eigen::Vector3d>& centres, const MosaicOptions& options);

}  // namespace stitch
