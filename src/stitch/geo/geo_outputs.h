#pragma once
// A geo-referenced run's trajectories in the files a surveyor opens: CSV with latitude,
// longitude and height, GeoJSON (RFC 7946: WGS84, [longitude, latitude, height]) and KML
// (absolute altitudes; KML's heights are above the geoid, ours above the ellipsoid: the file's
// description says so).

#include <cstdint>
#include <string>
#include <vector>

#include "stitch/geo/geodetic.h"

namespace stitch {

struct GeoTrack {
  std::string name;       // e.g. "map-0"
  std::string submaps;    // e.g. "0:1,0:2"
  std::string placed_by;  // how it was placed on Earth, e.g. "gnss"
  struct Point {
    int64_t t_ns = 0;
    int frame_index = -1;
    GeodeticPoint position;
  };
  std::vector<Point> points;  // in time order
};

// Each throws stitch::Error naming the file when it cannot be written (written atomically).
// "map,frame,t_ns,latitude_deg,longitude_deg,height_m", one line per camera position.
void WriteGeoTrajectoryCsv(const std::string& path, const std::vector<GeoTrack>& tracks);
// What WriteGeoTrajectoryCsv wrote: one track per map name, its points in the file's order (only
// name and points). Throws stitch::Error naming the file and line for another header, a field
// that is not a number or a time, or a position that is no place on Earth.
std::vector<GeoTrack> ReadGeoTrajectoryCsv(const std::string& path);
// Whether `path`'s first line is WriteGeoTrajectoryCsv's header.
bool IsGeoTrajectoryCsv(const std::string& path);
// A FeatureCollection of one LineString per track (a track of one point: a Point).
void WriteGeoJson(const std::string& path, const std::vector<GeoTrack>& tracks);
void WriteKml(const std::string& path, const std::vector<GeoTrack>& tracks);

}  // namespace stitch
