#pragma once
// A finished run placed on Earth: each of its maps (merged maps and submaps left on their own)
// placed in the local ENU frame by the GNSS fixes taken while its frames were flown
// (PlaceByGnss), its trajectory in WGS84 (geo/: CSV, GeoJSON, KML, georeference.json), and, where
// the ground truth is in that ENU frame (the synthetic flight), the absolute errors with no
// alignment to the truth at all.

#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "stitch/geo/geo_registration.h"
#include "stitch/geo/gnss_fix.h"
#include "stitch/io/colmap_model.h"
#include "stitch/io/ply.h"
#include "stitch/io/trajectory.h"
#include "stitch/records/pose_record.h"

namespace stitch {

// A placed map's cameras against the truth at the same times, in metres, unaligned.
struct AbsoluteErrors {
  int frames = 0;
  double horizontal_rms_m = 0.0;
  double vertical_rms_m = 0.0;
  int keyframes = 0;
  double keyframe_horizontal_rms_m = 0.0;
  double keyframe_vertical_rms_m = 0.0;
  // The scale the placed trajectory still needs to match the truth (a Sim3 fit), minus 1.
  double scale_error = 0.0;
};

// The cameras of `poses` moved into the ENU frame by `enu_from_map`, against `ground_truth`
// (in that frame) at the same times, interpolated between truth samples at most `max_gap_ns`
// apart; no alignment. Empty when no pose has a truth at its time.
std::optional<AbsoluteErrors> MeasureAbsolute(const std::vector<const PoseRecord*>& poses, const Sim3d& enu_from_map,
                                              const Trajectory& ground_truth, int64_t max_gap_ns = 50'000'000);

struct MapGeoReference {
  RunMap map;
  GeoPlacement placement;
  std::optional<AbsoluteErrors> absolute;  // placed, and the truth is in the ENU frame
};

struct RunGeoReference {
  GeodeticPoint origin;  // of the ENU frame: the truth's ENU origin where known, else the first fix
  std::string gnss_source;
  int fixes = 0;                      // usable fixes in the file
  std::vector<MapGeoReference> maps;  // as MapsOfRun orders them

  nlohmann::json ToJson() const;
  // One line per map for the terminal: placed where, by how many fixes, how far off.
  std::vector<std::string> Summary() const;
};

// Throws stitch::Error when the track has no usable fix.
RunGeoReference GeoReferenceRun(const std::vector<PoseRecord>& poses, int largest_component, const GnssTrack& gnss,
                                const Trajectory& ground_truth, const GeoReferenceOptions& options);

// FOLDER/{trajectory_wgs84.csv, trajectory.geojson, trajectory.kml, georeference.json}: the
// placed maps' camera positions (every frame of each), and how each map was placed or why not.
void WriteGeoOutputs(const std::string& folder, const RunGeoReference& geo, const std::vector<PoseRecord>& poses);

// `points` (in the frame of the map `component`) moved into the run's ENU frame in metres and
// written to `path` as PLY, its header naming the frame and the origin; false (nothing written)
// when that map was not placed on Earth.
bool WriteMapInEnu(const std::string& path, const RunGeoReference& geo, int component,
                   std::vector<ColouredPoint> points);
// The same points in WGS 84 / UTM (the zone of the run's origin: EPSG 326zz or 327zz; eastings
// and northings in metres, heights above the ellipsoid) as LAS 1.2 (las.h), what a surveyor's
// point-cloud tools open; false (nothing written) when that map was not placed on Earth. Throws
// stitch::Error naming the file when it cannot be written, or for an origin UTM does not cover.
bool WriteMapLas(const std::string& path, const RunGeoReference& geo, int component,
                 const std::vector<ColouredPoint>& points);
// The COLMAP model `model` (in the frame of the map `component`) moved into the run's ENU frame
// in metres: every camera centre and point by the map's placement, every image's pose turned with
// it, the cameras and tracks as they were (a similarity moves no projection). Written to `dir`
// (cameras.txt, images.txt, points3D.txt and georeference.txt, which names the frame and its
// origin, as COLMAP's own files cannot); false (nothing written) when that map was not placed on
// Earth. Throws stitch::Error naming the file when it cannot be written.
bool WriteColmapModelInEnu(const std::string& dir, const RunGeoReference& geo, int component, ColmapModel model);

}  // namespace stitch
