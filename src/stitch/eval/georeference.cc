#include "stitch/eval/georeference.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>

#include "stitch/geo/geo_outputs.h"
#include "stitch/geo/las.h"
#include "stitch/geometry/similarity.h"
#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace fs = std::filesystem;

namespace stitch {

std::optional<AbsoluteErrors> MeasureAbsolute(const std::vector<const PoseRecord*>& poses, const Sim3d& enu_from_map,
                                              const Trajectory& ground_truth, int64_t max_gap_ns) {
  AbsoluteErrors e;
  double horizontal = 0, vertical = 0, key_horizontal = 0, key_vertical = 0;
  std::vector<Eigen::Vector3d> placed, truth;
  for (const PoseRecord* p : poses) {
    const std::optional<Rigid3d> true_pose = ground_truth.PoseAt(p->t_ns, max_gap_ns);
    if (!true_pose) continue;
    const Eigen::Vector3d at = enu_from_map * p->world_from_cam.translation;
    const Eigen::Vector3d d = at - true_pose->translation;
    const double h = d.x() * d.x() + d.y() * d.y(), v = d.z() * d.z();
    ++e.frames;
    horizontal += h;
    vertical += v;
    if (p->is_keyframe) {
      ++e.keyframes;
      key_horizontal += h;
      key_vertical += v;
    }
    placed.push_back(at);
    truth.push_back(true_pose->translation);
  }
  if (e.frames == 0) return std::nullopt;
  e.horizontal_rms_m = std::sqrt(horizontal / e.frames);
  e.vertical_rms_m = std::sqrt(vertical / e.frames);
  if (e.keyframes > 0) {
    e.keyframe_horizontal_rms_m = std::sqrt(key_horizontal / e.keyframes);
    e.keyframe_vertical_rms_m = std::sqrt(key_vertical / e.keyframes);
  }
  try {
    e.scale_error = AlignPoints(placed, truth, true).scale - 1.0;
  } catch (const Error&) {
    e.scale_error = 0.0;  // collinear: the scale is still the placement's; not measured
  }
  return e;
}

RunGeoReference GeoReferenceRun(const std::vector<PoseRecord>& poses, int largest_component, const GnssTrack& gnss,
                                const Trajectory& ground_truth, const GeoReferenceOptions& options) {
  RunGeoReference geo;
  geo.gnss_source = gnss.source;
  const GnssFix* first = nullptr;
  for (const GnssFix& f : gnss.fixes) {
    if (!f.usable()) continue;
    if (!first) first = &f;
    ++geo.fixes;
  }
  if (!first) throw Error("the GNSS track has no usable fix");
  geo.origin = gnss.ground_truth_enu_origin ? *gnss.ground_truth_enu_origin : first->position;
  const LocalTangentPlane plane(geo.origin);
  const std::vector<EnuFix> fixes = ToEnu(gnss.fixes, plane);
  std::map<int, std::vector<const PoseRecord*>> by_component;
  for (const PoseRecord& p : poses) by_component[p.component].push_back(&p);
  const std::vector<RunMap> maps = MapsOfRun(poses, largest_component);
  std::vector<Trajectory> trajectories(maps.size());
  std::vector<MapToPlace> to_place;
  for (size_t i = 0; i < maps.size(); ++i) {
    for (const PoseRecord* p : by_component[maps[i].component]) trajectories[i].Add({p->t_ns, p->world_from_cam});
    to_place.push_back({&trajectories[i], &fixes});
  }
  std::vector<GeoPlacement> placements = PlaceMapsByGnss(to_place, options);
  for (size_t i = 0; i < maps.size(); ++i) {
    MapGeoReference m;
    m.map = maps[i];
    m.placement = std::move(placements[i]);
    if (m.placement.placed && gnss.ground_truth_enu_origin && !ground_truth.empty()) {
      m.absolute = MeasureAbsolute(by_component[maps[i].component], m.placement.enu_from_map, ground_truth);
    }
    geo.maps.push_back(std::move(m));
  }
  return geo;
}

nlohmann::json RunGeoReference::ToJson() const {
  nlohmann::json list = nlohmann::json::array();
  for (const MapGeoReference& m : maps) {
    const GeoPlacement& p = m.placement;
    nlohmann::json map = {{"map", m.map.name},
                          {"submaps", m.map.SubmapNames()},
                          {"frames", m.map.frames},
                          {"largest", m.map.largest},
                          {"placed", p.placed},
                          {"placed_by", p.placed ? p.method : ""},
                          {"fixes_matched", p.fixes_matched},
                          {"inliers", p.inliers},
                          {"spread_m", p.spread_m}};
    if (!p.placed) map["why_not"] = p.why_not;
    if (p.inliers > 0) {
      const Sim3d& s = p.enu_from_map;
      map["horizontal_rms_m"] = p.horizontal_rms_m;
      map["vertical_rms_m"] = p.vertical_rms_m;
      map["enu_from_map"] = {{"scale", s.scale},
                             {"rotation_xyzw", {s.rotation.x(), s.rotation.y(), s.rotation.z(), s.rotation.w()}},
                             {"translation", {s.translation.x(), s.translation.y(), s.translation.z()}}};
      nlohmann::json spans = nlohmann::json::array();
      for (const auto& [from, to] : p.outlier_spans) spans.push_back({from, to});
      map["outlier_spans_ns"] = spans;
      if (p.disagreement) {
        map["disagreeing_fixes"] = {{"fixes", p.disagreement->fixes},
                                    {"first_ns", p.disagreement->first_ns},
                                    {"last_ns", p.disagreement->last_ns},
                                    {"apart_m", p.disagreement->apart_m}};
      }
    }
    if (m.absolute) {
      const AbsoluteErrors& e = *m.absolute;
      map["absolute"] = {{"frames", e.frames},
                         {"horizontal_rms_m", e.horizontal_rms_m},
                         {"vertical_rms_m", e.vertical_rms_m},
                         {"keyframes", e.keyframes},
                         {"keyframe_horizontal_rms_m", e.keyframe_horizontal_rms_m},
                         {"keyframe_vertical_rms_m", e.keyframe_vertical_rms_m},
                         {"scale_error", e.scale_error}};
    }
    list.push_back(map);
  }
  return {{"origin",
           {{"latitude_deg", origin.latitude_deg},
            {"longitude_deg", origin.longitude_deg},
            {"height_m", origin.height_m},
            {"crs", "EPSG:4979 (WGS 84, ellipsoidal height)"}}},
          {"frame", "local ENU at the origin: x east, y north, z up, metres"},
          {"gnss_source", gnss_source},
          {"fixes", fixes},
          {"maps", list}};
}

std::vector<std::string> RunGeoReference::Summary() const {
  std::vector<std::string> lines;
  char line[640];
  std::snprintf(line, sizeof(line), "  on Earth          %d GNSS fixes (%s); ENU origin %.6f, %.6f, %.1f m (geo/)",
                fixes, gnss_source.empty() ? "gnss.csv" : gnss_source.c_str(), origin.latitude_deg,
                origin.longitude_deg, origin.height_m);
  lines.push_back(line);
  for (const MapGeoReference& m : maps) {
    const GeoPlacement& p = m.placement;
    if (!p.placed) {
      std::snprintf(line, sizeof(line), "    %s (%d frames) not placed: %s", m.map.name.c_str(), m.map.frames,
                    p.why_not.c_str());
    } else {
      int written = std::snprintf(line, sizeof(line),
                                  "    %s (%d frames) placed by %d of %d fixes%s: %.2f m horizontal, %.2f m vertical "
                                  "RMS from them",
                                  m.map.name.c_str(), m.map.frames, p.inliers, p.fixes_matched,
                                  p.method == "gnss"         ? ""
                                  : p.method == "gnss+level" ? " (levelled by the cameras' stated up axis)"
                                  : p.method == "gnss+camera-up"
                                      ? " (along a line: with the cameras' up)"
                                      : " (along a line: with the cameras' up as the run's other maps show it)",
                                  p.horizontal_rms_m, p.vertical_rms_m);
      if (p.disagreement && written > 0 && written < static_cast<int>(sizeof(line))) {
        written += std::snprintf(line + written, sizeof(line) - written,
                                 "; %d fixes from %.1f s to %.1f s agree with each other but put it %.1f m off: a "
                                 "receiver that jumped or was spoofed, not followed",
                                 p.disagreement->fixes, p.disagreement->first_ns * 1e-9, p.disagreement->last_ns * 1e-9,
                                 p.disagreement->apart_m);
      }
      if (m.absolute && written > 0 && written < static_cast<int>(sizeof(line))) {
        // A flight without keyframes of its own (localize only) is judged by its frames.
        const AbsoluteErrors& a = *m.absolute;
        const bool by_keyframes = a.keyframes > 0;
        std::snprintf(line + written, sizeof(line) - written,
                      "; against the truth, unaligned: %s %.2f m horizontal, %.2f m vertical RMS, scale off by %.2f%%",
                      by_keyframes ? "keyframes" : "frames",
                      by_keyframes ? a.keyframe_horizontal_rms_m : a.horizontal_rms_m,
                      by_keyframes ? a.keyframe_vertical_rms_m : a.vertical_rms_m, 100.0 * a.scale_error);
      }
    }
    lines.push_back(line);
  }
  return lines;
}

void WriteGeoOutputs(const std::string& folder, const RunGeoReference& geo, const std::vector<PoseRecord>& poses) {
  fs::create_directories(folder);
  const LocalTangentPlane plane(geo.origin);
  std::map<int, const MapGeoReference*> placed;
  for (const MapGeoReference& m : geo.maps) {
    if (m.placement.placed) placed[m.map.component] = &m;
  }
  std::map<int, GeoTrack> tracks;
  for (const PoseRecord& p : poses) {
    const auto it = placed.find(p.component);
    if (it == placed.end()) continue;
    GeoTrack& track = tracks[p.component];
    const Eigen::Vector3d enu = it->second->placement.enu_from_map * p.world_from_cam.translation;
    track.points.push_back({p.t_ns, p.frame_index, plane.ToGeodetic(enu)});
  }
  std::vector<GeoTrack> ordered;
  for (const MapGeoReference& m : geo.maps) {
    if (!m.placement.placed) continue;
    GeoTrack& track = tracks[m.map.component];
    track.name = m.map.name;
    track.submaps = m.map.SubmapNames();
    track.placed_by = m.placement.method;
    ordered.push_back(std::move(track));
  }
  WriteGeoTrajectoryCsv((fs::path(folder) / "trajectory_wgs84.csv").string(), ordered);
  WriteGeoJson((fs::path(folder) / "trajectory.geojson").string(), ordered);
  WriteKml((fs::path(folder) / "trajectory.kml").string(), ordered);
  WriteFileAtomically((fs::path(folder) / "georeference.json").string(), geo.ToJson().dump(1) + "\n");
}

namespace {

// The placement of the map `component`, where it was placed on Earth.
const MapGeoReference* PlacedMap(const RunGeoReference& geo, int component) {
  const auto placed = std::find_if(geo.maps.begin(), geo.maps.end(), [&](const MapGeoReference& m) {
    return m.map.component == component && m.placement.placed;
  });
  return placed == geo.maps.end() ? nullptr : &*placed;
}

// The ENU frame's words for a file's header: its axes, its origin, the map placed in it.
std::string EnuFrameText(const RunGeoReference& geo, const MapGeoReference& placed) {
  char frame[400];
  std::snprintf(frame, sizeof(frame),
                "east-north-up, metres (x east, y north, z up), origin at latitude %.9f, longitude %.9f (WGS84), "
                "height %.3f m as the GNSS fixes state it; %s placed by GNSS (georeference.json)",
                geo.origin.latitude_deg, geo.origin.longitude_deg, geo.origin.height_m, placed.map.name.c_str());
  return frame;
}

}  // namespace

bool WriteMapInEnu(const std::string& path, const RunGeoReference& geo, int component,
                   std::vector<ColouredPoint> points) {
  const MapGeoReference* placed = PlacedMap(geo, component);
  if (!placed) return false;
  const Sim3d& enu_from_map = placed->placement.enu_from_map;
  for (ColouredPoint& point : points) {
    point.position = (enu_from_map * point.position.cast<double>()).cast<float>();
  }
  WritePly(path, points, EnuFrameText(geo, *placed));
  return true;
}

bool WriteColmapModelInEnu(const std::string& dir, const RunGeoReference& geo, int component, ColmapModel model) {
  const MapGeoReference* placed = PlacedMap(geo, component);
  if (!placed) return false;
  const Sim3d& enu_from_map = placed->placement.enu_from_map;
  for (ColmapImage& image : model.images) {
    image.cam_from_world = TransformPose(enu_from_map, image.cam_from_world.Inverse()).Inverse();
  }
  for (ColmapPoint& point : model.points) point.position = enu_from_map * point.position;
  WriteColmapModel(model, dir);
  WriteFileAtomically(
      (fs::path(dir) / "georeference.txt").string(),
      "# The frame of this COLMAP model (cameras.txt, images.txt, points3D.txt)\n" + EnuFrameText(geo, *placed) + "\n");
  return true;
}

bool WriteMapLas(const std::string& path, const RunGeoReference& geo, int component,
                 const std::vector<ColouredPoint>& points) {
  const MapGeoReference* placed = PlacedMap(geo, component);
  if (!placed) return false;
  const LocalTangentPlane plane(geo.origin);
  const UtmZone zone = UtmZoneOf(geo.origin);
  LasCloud cloud;
  cloud.epsg = zone.epsg();
  cloud.points.reserve(points.size());
  for (const ColouredPoint& point : points) {
    const GeodeticPoint on_earth = plane.ToGeodetic(placed->placement.enu_from_map * point.position.cast<double>());
    LasPoint las;
    las.position << ToUtm(on_earth, zone), on_earth.height_m;
    las.red = point.red;
    las.green = point.green;
    las.blue = point.blue;
    cloud.points.push_back(las);
  }
  WriteLas(path, cloud);
  return true;
}

}  // namespace stitch
