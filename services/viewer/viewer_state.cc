#include "services/viewer/viewer_state.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>

#include <nlohmann/json.hpp>

#include "services/common/convert.h"
#include "stitch/geo/geodetic.h"
#include "stitch/mosaic/live_mosaic.h"
#include "stitch/util/error.h"
#include "stitch/util/ids.h"
#include "stitch/util/statistics.h"

namespace stitch {

namespace {

// Submaps, edges, keyframes and log lines a global map may hold to be shown.
constexpr int32_t kMaxSubmaps = 10000;
constexpr size_t kMaxPageKeyframes = 50000;
constexpr size_t kFrameRateWindow = 30;

const uint8_t kPalette[][3] = {{30, 90, 200}, {220, 40, 40}, {40, 160, 40}, {180, 40, 180},  {220, 150, 20},
                               {0, 140, 140}, {160, 60, 90}, {200, 110, 0}, {100, 100, 100}, {180, 180, 60}};

bool Finite(double value) {
  return std::isfinite(value);
}

nlohmann::json Vector(const Eigen::Vector3d& v) {
  return nlohmann::json::array({v.x(), v.y(), v.z()});
}

nlohmann::json Similarity(const Sim3d& s) {
  return {{"scale", s.scale},
          {"rotation_wxyz", {s.rotation.w(), s.rotation.x(), s.rotation.y(), s.rotation.z()}},
          {"translation", Vector(s.translation)}};
}

}  // namespace

std::string SubmapColour(int index) {
  const uint8_t* rgb = kPalette[((index % 10) + 10) % 10];
  char text[8];
  std::snprintf(text, sizeof(text), "#%02x%02x%02x", rgb[0], rgb[1], rgb[2]);
  return text;
}

bool ViewerState::Refuse(std::string* why, const std::string& what) {
  ++refused_;
  if (why) *why = what;
  return false;
}

bool ViewerState::OnGlobalMap(const stitch::global_map_t& message, std::string* why) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (message.num_submaps > kMaxSubmaps) return Refuse(why, "more than 10000 submaps");
  std::map<int64_t, std::pair<int, Sim3d>> placement;
  try {
    for (const stitch::submap_placement_t& p : message.submaps) {
      if (!SubmapId(p.submap_id).valid() || p.component < 0) return Refuse(why, "a submap without id or merged map");
      placement[p.submap_id] = {p.component, FromMessage(p.world_from_submap)};
    }
    for (const stitch::trajectory_pose_t& p : message.trajectory) FromMessage(p.world_from_cam);
    for (const stitch::map_on_earth_t& e : message.on_earth) {
      FromMessage(e.enu_from_world);
      if (e.component < 0) return Refuse(why, "a place on Earth for no merged map");
      if (!WhyNotOnEarth({e.origin_latitude_deg, e.origin_longitude_deg, e.origin_height_m}).empty() ||
          !(e.horizontal_rms_m >= 0 && e.horizontal_rms_m < 1e6)) {
        return Refuse(why, "a merged map's place on Earth has no origin on Earth or no accuracy");
      }
    }
  } catch (const Error& e) {
    return Refuse(why, e.what());
  }
  for (const stitch::submap_edge_t& e : message.edges) {
    if (!Finite(e.strength) || !Finite(e.median_angle_deg)) return Refuse(why, "an edge's strength is not finite");
    if (!(e.gnss_sigma_m >= 0 && e.gnss_sigma_m < 1e6)) {
      return Refuse(why, "an edge's GNSS standard error is not a distance");
    }
  }
  if (global_map_ && message.header.sender_session == global_map_->header.sender_session &&
      message.revision <= global_map_->revision) {
    return true;  // an older one, overtaken
  }
  global_map_ = message;
  placement_ = std::move(placement);
  ++map_revision_;
  return true;
}

bool ViewerState::OnMapCloud(const stitch::map_cloud_t& message, std::string* why) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (message.num_submaps > kMaxSubmaps) return Refuse(why, "more than 10000 submaps");
  int64_t points = 0;
  for (int32_t count : message.point_counts) {
    if (count < 0) return Refuse(why, "a negative point count");
    points += count;
  }
  if (points * 3 != message.num_coordinates) {
    return Refuse(why, "its point counts add up to " + std::to_string(points) + " points for " +
                           std::to_string(message.num_coordinates) + " coordinates");
  }
  if (cloud_ && message.header.sender_session == cloud_->header.sender_session &&
      message.revision <= cloud_->revision) {
    return true;
  }
  cloud_ = message;
  ++cloud_revision_;
  return true;
}

bool ViewerState::OnTrackingStatus(const stitch::tracking_status_t& message, double now_s, std::string* why) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (message.frame_index < 0) return Refuse(why, "a negative frame index");
  if (message.detail.size() > 1000) return Refuse(why, "a detail over 1000 characters");
  Aircraft& a = aircraft_[message.header.agent];
  a.status = message;
  a.frame_times.push_back(now_s);
  while (a.frame_times.size() > kFrameRateWindow) a.frame_times.pop_front();
  ++a.frames;
  return true;
}

bool ViewerState::OnPose(const stitch::frame_pose_t& message, std::string* why) {
  try {
    FromFloatPose(message.cam_from_submap, "frame_pose cam_from_submap");
  } catch (const Error& e) {
    std::lock_guard<std::mutex> lock(mutex_);
    return Refuse(why, e.what());
  }
  std::lock_guard<std::mutex> lock(mutex_);
  if (!SubmapId(message.submap_id).valid()) return Refuse(why, "names no submap");
  Aircraft& a = aircraft_[message.header.agent];
  if (a.pose && a.pose->header.sender_session == message.header.sender_session &&
      a.pose->frame_index > message.frame_index) {
    return true;  // an older frame, overtaken
  }
  a.pose = message;
  return true;
}

bool ViewerState::OnLinkStatus(const stitch::link_status_t& message, std::string* why) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!Finite(message.send_rate_bytes_per_s) || !Finite(message.backlog_s) || !Finite(message.budget_bytes_per_s) ||
      !Finite(message.seconds_since_peer)) {
    return Refuse(why, "a figure is not finite");
  }
  if (message.forward.size() > 1000 || message.peer.size() > 1000) return Refuse(why, "a text over 1000 characters");
  auto& links = aircraft_[message.header.agent].links;
  if (links.size() >= 4 && !links.count(message.forward)) return Refuse(why, "a fifth link bridge");
  links[message.forward] = message;
  return true;
}

namespace {
constexpr size_t kMaxMosaicBytes = size_t{512} << 20;  // the tiles held, PNG
constexpr size_t kMaxTileBytes = size_t{8} << 20;

// A PNG's size from its IHDR chunk (bytes 16-23), without decoding it.
std::optional<std::pair<uint32_t, uint32_t>> PngSize(const std::vector<uint8_t>& png) {
  static const uint8_t kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  if (png.size() < 24 || std::memcmp(png.data(), kSignature, 8) != 0 || std::memcmp(png.data() + 12, "IHDR", 4) != 0) {
    return std::nullopt;
  }
  const auto word = [&](size_t at) {
    return (uint32_t{png[at]} << 24) | (uint32_t{png[at + 1]} << 16) | (uint32_t{png[at + 2]} << 8) | png[at + 3];
  };
  return std::make_pair(word(16), word(20));
}
}  // namespace

bool ViewerState::OnMosaicTile(const stitch::mosaic_tile_t& message, int64_t now_utime, std::string* why) {
  if (message.revision < 1 || message.version < 1) return Refuse(why, "a mosaic tile's revision or version below 1");
  if (message.tile_px < 16 || message.tile_px > 4096) return Refuse(why, "a mosaic tile's side outside 16-4096 pixels");
  if (std::abs(message.col) > 1'000'000 || std::abs(message.row) > 1'000'000) {
    return Refuse(why, "a mosaic tile more than 10^6 tiles out");
  }
  if (!Finite(message.origin_x) || !Finite(message.origin_y) || !(message.gsd > 0) || !Finite(message.gsd)) {
    return Refuse(why, "a mosaic grid that is not finite");
  }
  try {
    FromMessage(message.ground_from_map);
  } catch (const Error& e) {
    return Refuse(why, std::string("a mosaic frame: ") + e.what());
  }
  if (message.png.size() > kMaxTileBytes) return Refuse(why, "a mosaic tile over 8 MB");
  if (!message.png.empty()) {
    const auto size = PngSize(message.png);
    if (!size || size->first != static_cast<uint32_t>(message.tile_px) ||
        size->second != static_cast<uint32_t>(message.tile_px)) {
      return Refuse(why, "a mosaic tile that is no PNG of its side");
    }
  }
  std::lock_guard<std::mutex> lock(mutex_);
  if (mosaic_frame_ && message.revision < mosaic_frame_->revision) return true;  // an older mosaic's: not shown
  if (!mosaic_frame_ || message.revision > mosaic_frame_->revision) {
    mosaic_tiles_.clear();
    mosaic_bytes_ = 0;
  }
  mosaic_frame_ = message;
  mosaic_frame_->png.clear();
  mosaic_frame_->num_bytes = 0;
  const std::pair<int, int> key{message.col, message.row};
  const auto held = mosaic_tiles_.find(key);
  if (held != mosaic_tiles_.end()) {
    if (held->second.version > message.version) return true;  // a newer one is held
    mosaic_bytes_ -= held->second.png->size();
    mosaic_tiles_.erase(held);
  }
  if (!message.png.empty()) {
    if (mosaic_bytes_ + message.png.size() > kMaxMosaicBytes) return Refuse(why, "mosaic tiles over 512 MB");
    mosaic_tiles_[key] = {message.version, std::make_shared<const std::string>(message.png.begin(), message.png.end())};
    mosaic_bytes_ += message.png.size();
  }
  // One sample per update that laid pictures (its tiles all carry the same time).
  if (message.newest_picture_utime > 0 && message.newest_picture_utime != mosaic_latency_utime_) {
    mosaic_latency_utime_ = message.newest_picture_utime;
    if (mosaic_latencies_s_.size() >= 10000) mosaic_latencies_s_.erase(mosaic_latencies_s_.begin());
    mosaic_latencies_s_.push_back(1e-6 * static_cast<double>(now_utime - message.newest_picture_utime));
  }
  return true;
}

std::shared_ptr<const std::string> ViewerState::MosaicTilePng(int col, int row) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto tile = mosaic_tiles_.find({col, row});
  return tile == mosaic_tiles_.end() ? nullptr : tile->second.png;
}

std::string ViewerState::LiveJson(double now_s) const {
  std::lock_guard<std::mutex> lock(mutex_);
  nlohmann::json live;
  live["type"] = "live";
  live["map_revision"] = map_revision_;
  live["cloud_revision"] = cloud_revision_;
  live["refused"] = refused_;
  nlohmann::json aircraft = nlohmann::json::object();
  for (const auto& [agent, a] : aircraft_) {
    nlohmann::json j;
    if (a.status) {
      const stitch::tracking_status_t& s = *a.status;
      double fps = 0;
      if (a.frame_times.size() >= 2 && now_s - a.frame_times.back() < 2.0) {
        const double span = a.frame_times.back() - a.frame_times.front();
        if (span > 0) fps = static_cast<double>(a.frame_times.size() - 1) / span;
      }
      j["tracking"] = {{"state", MessageStateName(s.state)},
                       {"reason", s.reason},
                       {"detail", s.detail},
                       {"frame", s.frame_index},
                       {"frames", a.frames},
                       {"fps", fps},
                       {"submap", SubmapName(SubmapId(s.submap_id))},
                       {"features", s.num_features},
                       {"tracked_points", s.num_tracked_points},
                       {"submap_keyframes", s.submap_keyframes},
                       {"submaps_closed", s.submaps_closed},
                       {"tracking_ms", s.tracking_ms},
                       {"mapper_connected", s.mapper_connected != 0},
                       {"seconds_ago", now_s - a.frame_times.back()}};
      // How far the map on the page is behind the tracker: the keyframes of its submap the
      // latest cloud holds (-1: none of it yet).
      int map_keyframes = -1;
      if (cloud_) {
        for (size_t k = 0; k < cloud_->submap_ids.size() && k < cloud_->keyframe_counts.size(); ++k) {
          if (cloud_->submap_ids[k] == s.submap_id) map_keyframes = cloud_->keyframe_counts[k];
        }
      }
      j["tracking"]["map_keyframes"] = map_keyframes;
    }
    if (a.pose) {
      const stitch::frame_pose_t& p = *a.pose;
      const Rigid3d submap_from_cam = FromFloatPose(p.cam_from_submap, "frame_pose").Inverse();
      nlohmann::json camera{{"frame", p.frame_index}, {"submap", SubmapName(SubmapId(p.submap_id))}};
      const auto placed = placement_.find(p.submap_id);
      if (placed != placement_.end()) {
        const Sim3d& world_from_submap = placed->second.second;
        const Sim3d pose = world_from_submap * Sim3d(1.0, submap_from_cam.rotation, submap_from_cam.translation);
        camera["component"] = placed->second.first;
        camera["position"] = Vector(pose.translation);
        camera["rotation_wxyz"] = {pose.rotation.w(), pose.rotation.x(), pose.rotation.y(), pose.rotation.z()};
        camera["scale"] = world_from_submap.scale;
      } else {
        camera["component"] = nullptr;  // its submap is not on the ground's map yet
      }
      j["camera"] = camera;
    }
    nlohmann::json links = nlohmann::json::array();
    for (const auto& [forward, l] : a.links) {
      links.push_back({{"forward", l.forward},
                       {"peer", l.peer},
                       {"authenticated", l.authenticated != 0},
                       {"budget_bytes_per_s", l.budget_bytes_per_s},
                       {"send_rate_bytes_per_s", l.send_rate_bytes_per_s},
                       {"backlog_s", l.backlog_s},
                       {"messages_received", l.messages_received},
                       {"messages_given_up", l.messages_given_up},
                       {"fragments_repaired", l.fragments_repaired},
                       {"datagrams_refused", l.datagrams_refused},
                       {"seconds_since_peer", l.seconds_since_peer}});
    }
    if (!links.empty()) j["links"] = links;
    aircraft[agent] = j;
  }
  live["aircraft"] = aircraft;
  if (mosaic_frame_) {
    const stitch::mosaic_tile_t& m = *mosaic_frame_;
    const Sim3d g = FromMessage(m.ground_from_map);
    nlohmann::json tiles = nlohmann::json::array();
    for (const auto& [key, tile] : mosaic_tiles_) tiles.push_back({key.first, key.second, tile.version});
    live["mosaic"] = {{"revision", m.revision},
                      // "earth": the maps the fixes place, in their ENU frame (map.on_earth)
                      {"frame", m.frame_submap == LiveMosaic::kFrameOnEarth ? std::string("earth")
                                                                            : SubmapName(SubmapId(m.frame_submap))},
                      {"ground_from_map", Similarity(g)},
                      {"origin", {m.origin_x, m.origin_y}},
                      {"gsd", m.gsd},
                      {"tile_px", m.tile_px},
                      {"tiles", tiles},
                      {"latency_s", mosaic_latencies_s_.empty() ? -1.0 : mosaic_latencies_s_.back()},
                      {"latency_median_s", mosaic_latencies_s_.empty() ? -1.0 : Median(mosaic_latencies_s_)},
                      {"latency_max_s", mosaic_latencies_s_.empty() ? -1.0
                                                                    : *std::max_element(mosaic_latencies_s_.begin(),
                                                                                        mosaic_latencies_s_.end())}};
  }
  return live.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);  // texts from the bus may be any bytes
}

std::string ViewerState::MapJson() const {
  std::lock_guard<std::mutex> lock(mutex_);
  nlohmann::json map;
  map["type"] = "map";
  map["map_revision"] = map_revision_;
  nlohmann::json submaps = nlohmann::json::array(), edges = nlohmann::json::array(), log = nlohmann::json::array();
  int keyframes = 0, merged_maps = 0;
  if (global_map_) {
    std::map<int64_t, int> colour;
    std::map<int, int> members;  // component -> submaps
    for (const auto& p : global_map_->submaps) {
      colour.emplace(p.submap_id, static_cast<int>(colour.size()));
      ++members[p.component];
    }
    for (const auto& [component, count] : members) merged_maps += count > 1;
    // Keyframe trajectories, in frame order per submap, thinned to a bound for the page.
    std::map<int64_t, std::vector<std::pair<int, Eigen::Vector3d>>> trajectories;
    const size_t stride =
        std::max<size_t>(1, (global_map_->trajectory.size() + kMaxPageKeyframes - 1) / kMaxPageKeyframes);
    for (size_t i = 0; i < global_map_->trajectory.size(); i += stride) {
      const stitch::trajectory_pose_t& p = global_map_->trajectory[i];
      trajectories[p.submap_id].push_back(
          {p.frame_index, Eigen::Vector3d(p.world_from_cam.translation[0], p.world_from_cam.translation[1],
                                          p.world_from_cam.translation[2])});
    }
    for (const stitch::submap_placement_t& p : global_map_->submaps) {
      auto& list = trajectories[p.submap_id];
      std::sort(list.begin(), list.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
      nlohmann::json positions = nlohmann::json::array();
      for (const auto& [frame, position] : list) positions.push_back(Vector(position));
      keyframes += p.num_keyframes;
      submaps.push_back({{"id", SubmapName(SubmapId(p.submap_id))},
                         {"agent", p.agent},
                         {"component", p.component},
                         {"merged", members[p.component] > 1},
                         {"keyframes", p.num_keyframes},
                         {"points", p.num_points},
                         {"closed", p.closed != 0},
                         {"colour", SubmapColour(colour[p.submap_id])},
                         {"trajectory", positions}});
    }
    for (const stitch::submap_edge_t& e : global_map_->edges) {
      edges.push_back({{"a", SubmapName(SubmapId(e.submap_a))},
                       {"b", SubmapName(SubmapId(e.submap_b))},
                       {"C", e.strength},
                       {"frames", e.connected_frames},
                       {"points", e.map_points},
                       {"angle_deg", e.median_angle_deg},
                       {"tree", e.in_spanning_tree != 0},
                       {"refused", e.refused},
                       {"gnss_sigma_m", e.gnss_sigma_m}});
    }
    for (const std::string& line : global_map_->merge_log) log.push_back(line);
  }
  // Where the fixes place each merged map: metres per unit of its frame, and east, north and up
  // in its frame (the page's scale bar and north arrow).
  nlohmann::json on_earth = nlohmann::json::array();
  if (global_map_) {
    for (const stitch::map_on_earth_t& e : global_map_->on_earth) {
      const Sim3d enu_from_world = FromMessage(e.enu_from_world);  // checked on arrival
      const Eigen::Matrix3d world_from_enu = enu_from_world.rotation.conjugate().toRotationMatrix();
      on_earth.push_back({{"component", e.component},
                          {"enu_from_world", Similarity(enu_from_world)},
                          {"metres_per_unit", enu_from_world.scale},
                          {"east", Vector(world_from_enu.col(0))},
                          {"north", Vector(world_from_enu.col(1))},
                          {"up", Vector(world_from_enu.col(2))},
                          {"origin", {e.origin_latitude_deg, e.origin_longitude_deg, e.origin_height_m}},
                          {"fixes", e.inlier_fixes},
                          {"horizontal_rms_m", e.horizontal_rms_m}});
    }
  }
  map["on_earth"] = on_earth;
  map["submaps"] = submaps;
  map["edges"] = edges;
  map["merge_log"] = log;
  map["keyframes"] = keyframes;
  map["merged_maps"] = merged_maps;
  return map.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

std::string ViewerState::CloudBinary() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<float> positions;
  std::vector<uint8_t> colours, components;
  if (cloud_) {
    std::map<int64_t, int> colour;
    if (global_map_) {
      for (const auto& p : global_map_->submaps) colour.emplace(p.submap_id, static_cast<int>(colour.size()));
    }
    const int64_t total = cloud_->num_coordinates / 3;
    const int64_t stride =
        max_page_points_ <= 0 ? total + 1 : std::max<int64_t>(1, (total + max_page_points_ - 1) / max_page_points_);
    int64_t first = 0;
    for (int32_t s = 0; s < cloud_->num_submaps; ++s) {
      const auto known = colour.find(cloud_->submap_ids[s]);
      const uint8_t* rgb = kPalette[(known != colour.end() ? known->second : s) % 10];
      const uint8_t component = static_cast<uint8_t>(std::clamp(cloud_->components[s], 0, 255));
      for (int64_t i = first; i < first + cloud_->point_counts[s]; ++i) {
        if (i % stride != 0) continue;
        const float* xyz = &cloud_->positions[static_cast<size_t>(3 * i)];
        if (!std::isfinite(xyz[0]) || !std::isfinite(xyz[1]) || !std::isfinite(xyz[2])) continue;
        positions.insert(positions.end(), xyz, xyz + 3);
        colours.insert(colours.end(), rgb, rgb + 3);
        components.push_back(component);
      }
      first += cloud_->point_counts[s];
    }
  }
  const uint32_t header[4] = {0x4c435453u /* "STCL" */, static_cast<uint32_t>(cloud_revision_),
                              static_cast<uint32_t>(components.size()), 0};
  std::string bytes(sizeof(header) + positions.size() * sizeof(float) + colours.size() + components.size(), '\0');
  char* out = bytes.data();
  std::memcpy(out, header, sizeof(header));
  out += sizeof(header);
  if (!components.empty()) {  // (an empty vector's data() may be null, which memcpy may not get)
    std::memcpy(out, positions.data(), positions.size() * sizeof(float));
    out += positions.size() * sizeof(float);
    std::memcpy(out, colours.data(), colours.size());
    out += colours.size();
    std::memcpy(out, components.data(), components.size());
  }
  return bytes;
}

int64_t ViewerState::map_revision() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return map_revision_;
}

int64_t ViewerState::cloud_revision() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return cloud_revision_;
}

int64_t ViewerState::refused() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return refused_;
}

}  // namespace stitch
