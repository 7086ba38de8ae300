#include "stitch/geo/geo_outputs.h"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>

#include <nlohmann/json.hpp>

#include "stitch/geo/csv_fields.h"
#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace stitch {

namespace {

std::string XmlEscaped(const std::string& text) {
  std::string out;
  for (char c : text) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

constexpr const char* kTrajectoryHeader = "map,frame,t_ns,latitude_deg,longitude_deg,height_m";

// Degrees to 1e-9 (0.1 mm), metres to the millimetre.
nlohmann::json Coordinates(const GeodeticPoint& p) {
  const auto round = [](double value, double unit) { return std::round(value / unit) * unit; };
  return nlohmann::json::array({round(p.longitude_deg, 1e-9), round(p.latitude_deg, 1e-9), round(p.height_m, 1e-3)});
}

}  // namespace

void WriteGeoTrajectoryCsv(const std::string& path, const std::vector<GeoTrack>& tracks) {
  std::ostringstream out;
  out << kTrajectoryHeader << "\n";
  char line[200];
  for (const GeoTrack& track : tracks) {
    for (const GeoTrack::Point& p : track.points) {
      std::snprintf(line, sizeof(line), "%s,%d,%lld,%.9f,%.9f,%.3f\n", track.name.c_str(), p.frame_index,
                    static_cast<long long>(p.t_ns), p.position.latitude_deg, p.position.longitude_deg,
                    p.position.height_m);
      out << line;
    }
  }
  WriteFileAtomically(path, out.str());
}

bool IsGeoTrajectoryCsv(const std::string& path) {
  std::ifstream in(path);
  std::string line;
  return in && std::getline(in, line) && Trimmed(line) == kTrajectoryHeader;
}

std::vector<GeoTrack> ReadGeoTrajectoryCsv(const std::string& path) {
  std::vector<GeoTrack> tracks;
  std::map<std::string, size_t> track_of;
  bool header_seen = false;
  ForEachDataLine(
      path,
      [&](const std::string& line, int line_number) {
        const auto fail = [&](const std::string& why) -> Error {
          return Error(Str() << path << ":" << line_number << ": " << why);
        };
        const std::string text = Trimmed(line);
        if (!header_seen) {
          if (text != kTrajectoryHeader) {
            throw fail(std::string("expected the header line \"") + kTrajectoryHeader + "\"");
          }
          header_seen = true;
          return;
        }
        const std::vector<std::string> fields = SplitFields(text);
        if (fields.size() != 6) throw fail(Str() << fields.size() << " fields where a position has 6");
        GeoTrack::Point point;
        double frame = 0;
        if (!ParseNumber(fields[1], &frame) || frame != std::floor(frame) || std::abs(frame) > 1e9) {
          throw fail("frame is not a frame number: \"" + fields[1] + "\"");
        }
        point.frame_index = static_cast<int>(frame);
        if (!ParseTime(fields[2], &point.t_ns)) throw fail("t_ns is not a time in nanoseconds: \"" + fields[2] + "\"");
        double* numbers[] = {&point.position.latitude_deg, &point.position.longitude_deg, &point.position.height_m};
        for (int i = 0; i < 3; ++i) {
          if (!ParseNumber(fields[i + 3], numbers[i]))
            throw fail("field " + std::to_string(i + 4) + " is not a number");
        }
        if (const std::string why = WhyNotOnEarth(point.position); !why.empty()) throw fail(why);
        const std::string name = Trimmed(fields[0]);
        const auto [it, added] = track_of.try_emplace(name, tracks.size());
        if (added) {
          tracks.emplace_back();
          tracks.back().name = name;
        }
        tracks[it->second].points.push_back(point);
      },
      " the trajectory");
  if (!header_seen) throw Error(path + ": empty, where a trajectory's header was expected");
  return tracks;
}

void WriteGeoJson(const std::string& path, const std::vector<GeoTrack>& tracks) {
  nlohmann::json features = nlohmann::json::array();
  for (const GeoTrack& track : tracks) {
    if (track.points.empty()) continue;
    nlohmann::json geometry;
    if (track.points.size() == 1) {
      geometry = {{"type", "Point"}, {"coordinates", Coordinates(track.points.front().position)}};
    } else {
      nlohmann::json line = nlohmann::json::array();
      for (const GeoTrack::Point& p : track.points) line.push_back(Coordinates(p.position));
      geometry = {{"type", "LineString"}, {"coordinates", line}};
    }
    features.push_back({{"type", "Feature"},
                        {"geometry", geometry},
                        {"properties",
                         {{"map", track.name},
                          {"submaps", track.submaps},
                          {"placed_by", track.placed_by},
                          {"frames", track.points.size()},
                          {"height", "metres above the WGS84 ellipsoid"}}}});
  }
  const nlohmann::json collection = {{"type", "FeatureCollection"}, {"features", features}};
  WriteFileAtomically(path, collection.dump(1) + "\n");
}

void WriteKml(const std::string& path, const std::vector<GeoTrack>& tracks) {
  std::ostringstream out;
  out << "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
         "<kml xmlns=\"http://www.opengis.net/kml/2.2\">\n<Document>\n<name>stitch trajectories</name>\n";
  char coordinate[120];
  for (const GeoTrack& track : tracks) {
    if (track.points.empty()) continue;
    out << "<Placemark>\n<name>" << XmlEscaped(track.name) << "</name>\n<description>submaps "
        << XmlEscaped(track.submaps) << ", placed by " << XmlEscaped(track.placed_by)
        << "; heights above the WGS84 ellipsoid</description>\n";
    const bool point = track.points.size() == 1;
    out << (point ? "<Point>" : "<LineString>") << "<altitudeMode>absolute</altitudeMode><coordinates>\n";
    for (const GeoTrack::Point& p : track.points) {
      std::snprintf(coordinate, sizeof(coordinate), "%.9f,%.9f,%.3f\n", p.position.longitude_deg,
                    p.position.latitude_deg, p.position.height_m);
      out << coordinate;
    }
    out << "</coordinates>" << (point ? "</Point>" : "</LineString>") << "\n</Placemark>\n";
  }
  out << "</Document>\n</kml>\n";
  WriteFileAtomically(path, out.str());
}

}  // namespace stitch
