#include "services/merger/merger_messages.h"

#include <algorithm>

#include "services/common/convert.h"

namespace stitch {

stitch::global_map_t ToGlobalMapMessage(const Merger::Graph& graph, const std::map<SubmapId, SubmapReplica>& submaps,
                                        const std::map<SubmapId, std::string>& agent_of,
                                        const std::string& default_agent, const std::vector<MergeLogRecord>& log,
                                        size_t log_lines, const std::optional<GeodeticPoint>& enu_origin) {
  stitch::global_map_t m{};
  for (const auto& [id, placement] : graph.placement) {
    const SubmapReplica& replica = submaps.at(id);
    stitch::submap_placement_t p{};
    const auto agent = agent_of.find(id);
    p.agent = agent != agent_of.end() ? agent->second : default_agent;
    p.submap_id = id.value;
    p.component = placement.component;
    p.world_from_submap = ToMessage(placement.world_from_submap);
    p.num_keyframes = static_cast<int32_t>(replica.map.num_keyframes());
    p.num_points = static_cast<int32_t>(replica.map.num_points());
    p.closed = replica.closed;
    m.submaps.push_back(p);
  }
  m.num_submaps = static_cast<int32_t>(m.submaps.size());
  for (const SubmapEdge& e : graph.edges) {
    stitch::submap_edge_t edge{};
    edge.submap_a = e.a.value;
    edge.submap_b = e.b.value;
    edge.strength = e.strength;
    edge.connected_frames = e.connected_frames;
    edge.map_points = e.map_points;
    edge.median_angle_deg = e.median_angle_deg;
    edge.in_spanning_tree = InTree(e, graph.tree);
    edge.b_from_a = ToMessage(e.b_from_a);
    edge.refused = e.refused;
    edge.gnss_sigma_m = e.kind == EdgeKind::kGnss ? std::max(e.gnss_sigma_m, 1e-3) : 0.0;
    m.edges.push_back(edge);
  }
  m.num_edges = static_cast<int32_t>(m.edges.size());
  // The refined keyframe poses (after the pose graph and the bundle adjustment), when there are;
  // frames between keyframes follow the nearest one.
  for (const auto& [id, pose] : graph.keyframe_poses) {
    const Keyframe* keyframe = submaps.at(SubmapOf(id)).map.FindKeyframe(id);
    if (!keyframe) continue;
    stitch::trajectory_pose_t p{};
    p.frame_index = keyframe->frame_index;
    p.t_ns = keyframe->t_ns;
    p.submap_id = SubmapOf(id).value;
    p.component = graph.placement.at(SubmapOf(id)).component;
    p.is_keyframe = true;
    p.world_from_cam = ToMessage(pose);
    m.trajectory.push_back(p);
  }
  m.num_poses = static_cast<int32_t>(m.trajectory.size());
  for (size_t i = log.size() > log_lines ? log.size() - log_lines : 0; i < log.size(); ++i) {
    const MergeLogRecord& r = log[i];
    m.merge_log.push_back(r.event + "\t" + r.current_map + "\t" + r.unconnected + "\t" + r.merged_maps);
  }
  m.num_log_lines = static_cast<int32_t>(m.merge_log.size());
  if (enu_origin) {
    for (const auto& [component, on_earth] : graph.on_earth) {
      stitch::map_on_earth_t placed{};
      placed.component = component;
      placed.enu_from_world = ToMessage(on_earth.enu_from_world);
      placed.origin_latitude_deg = enu_origin->latitude_deg;
      placed.origin_longitude_deg = enu_origin->longitude_deg;
      placed.origin_height_m = enu_origin->height_m;
      placed.inlier_fixes = on_earth.inlier_fixes;
      placed.horizontal_rms_m = on_earth.horizontal_rms_m;
      m.on_earth.push_back(placed);
    }
  }
  m.num_on_earth = static_cast<int32_t>(m.on_earth.size());
  return m;
}

stitch::map_cloud_t ToMessage(const MergeSession::MapCloud& cloud) {
  stitch::map_cloud_t m{};
  m.revision = cloud.revision;
  m.points_in_maps = cloud.points_in_maps;
  for (const MergeSession::MapCloud::Submap& submap : cloud.submaps) {
    for (const Eigen::Vector3f& p : submap.positions) m.positions.insert(m.positions.end(), {p.x(), p.y(), p.z()});
    m.submap_ids.push_back(submap.id.value);
    m.components.push_back(submap.component);
    m.point_counts.push_back(static_cast<int32_t>(submap.positions.size()));
    m.keyframe_counts.push_back(submap.keyframes);
  }
  m.num_submaps = static_cast<int32_t>(m.submap_ids.size());
  m.num_coordinates = static_cast<int32_t>(m.positions.size());
  return m;
}

}  // namespace stitch
