#pragma once
// What the live viewer shows, built from the ground's messages: the merger's global map (submaps,
// their placements, edges, keyframe trajectories, merge log), its map cloud, and each aircraft's
// tracking status, pose stream and link status. Thread-safe: the bus's thread feeds it, the web
// server's threads read it. Every message has passed the bus's decode checks; the content checks
// here refuse (and count) what cannot be drawn: non-finite values, counts that do not add up.

#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "stitch/frame_pose_t.hpp"
#include "stitch/geometry/rigid3.h"
#include "stitch/global_map_t.hpp"
#include "stitch/link_status_t.hpp"
#include "stitch/map_cloud_t.hpp"
#include "stitch/mosaic_tile_t.hpp"
#include "stitch/tracking_status_t.hpp"

namespace stitch {

class ViewerState {
 public:
  explicit ViewerState(int max_page_points) : max_page_points_(max_page_points) {}

  // Each returns false (and counts it) for a message whose content cannot be shown; `why` says why.
  bool OnGlobalMap(const stitch::global_map_t& message, std::string* why);
  bool OnMapCloud(const stitch::map_cloud_t& message, std::string* why);
  bool OnTrackingStatus(const stitch::tracking_status_t& message, double now_s, std::string* why);
  bool OnPose(const stitch::frame_pose_t& message, std::string* why);
  bool OnLinkStatus(const stitch::link_status_t& message, std::string* why);
  // A tile of the merger's live mosaic; `now_utime`: this machine's wall clock (how long its
  // newest picture took from the aircraft). A newer revision drops every tile of the one before.
  bool OnMosaicTile(const stitch::mosaic_tile_t& message, int64_t now_utime, std::string* why);
  // Its PNG (empty when the tile is not held).
  std::shared_ptr<const std::string> MosaicTilePng(int col, int row) const;

  // The page's three updates. Live: each aircraft's tracking state, frame rate, camera pose in its
  // merged map, link figures (small, every push). Map: submaps, edges, keyframe trajectories and
  // the merge log (when the global map changes). Cloud: the points, binary (when they change):
  //   "STCL", uint32 revision, uint32 count, uint32 0, then float32 x, y, z per point, then
  //   uint8 r, g, b per point, then uint8 merged map (component, 255 above) per point; little-endian.
  // The live update holds the mosaic's index ("mosaic": its frame and grid, each tile held with
  // its version; the page fetches /mosaic/COL_ROW.png for those it has not).
  std::string LiveJson(double now_s) const;
  std::string MapJson() const;
  std::string CloudBinary() const;
  int64_t map_revision() const;
  int64_t cloud_revision() const;
  int64_t refused() const;

 private:
  struct Aircraft {
    std::optional<stitch::tracking_status_t> status;
    std::deque<double> frame_times;  // receive times of the last statuses (frame rate)
    int64_t frames = 0;
    std::optional<stitch::frame_pose_t> pose;
    // Each link bridge's newest status, by the channels it sends (`forward`): on the ground, the
    // ground's bridge and the aircraft's (whose status crosses the link with its channels).
    std::map<std::string, stitch::link_status_t> links;
  };
  bool Refuse(std::string* why, const std::string& what);

  const int max_page_points_;
  mutable std::mutex mutex_;
  std::map<std::string, Aircraft> aircraft_;
  std::optional<stitch::global_map_t> global_map_;
  std::map<int64_t, std::pair<int, Sim3d>> placement_;  // submap -> (component, world_from_submap)
  std::optional<stitch::map_cloud_t> cloud_;
  int64_t map_revision_ = 0, cloud_revision_ = 0, refused_ = 0;
  // The live mosaic: the newest revision's frame and grid (its first tile's), and its tiles.
  struct MosaicTile {
    int64_t version = 0;
    std::shared_ptr<const std::string> png;
  };
  std::optional<stitch::mosaic_tile_t> mosaic_frame_;  // png left empty
  std::map<std::pair<int, int>, MosaicTile> mosaic_tiles_;
  size_t mosaic_bytes_ = 0;
  std::vector<double> mosaic_latencies_s_;  // picture sent -> its tile here, the last 10,000
  int64_t mosaic_latency_utime_ = 0;        // the picture time of the last sample
};

// "#1e5ac8": the colour of the submap at `index` (in id order), as in map.ply.
std::string SubmapColour(int index);

}  // namespace stitch
