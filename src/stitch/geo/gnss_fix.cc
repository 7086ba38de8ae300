#include "stitch/geo/gnss_fix.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>

#include "stitch/geo/csv_fields.h"
#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace stitch {

namespace {

constexpr const char* kHeader =
    "t_ns,latitude_deg,longitude_deg,height_m,horizontal_accuracy_m,vertical_accuracy_m,fix";
constexpr GnssFixType kTypes[] = {GnssFixType::kNone, GnssFixType::k2d,       GnssFixType::k3d,
                                  GnssFixType::kDgps, GnssFixType::kRtkFloat, GnssFixType::kRtkFixed};

}  // namespace

const char* GnssFixTypeName(GnssFixType type) {
  switch (type) {
    case GnssFixType::kNone:
      return "none";
    case GnssFixType::k2d:
      return "2d";
    case GnssFixType::k3d:
      return "3d";
    case GnssFixType::kDgps:
      return "dgps";
    case GnssFixType::kRtkFloat:
      return "rtk_float";
    case GnssFixType::kRtkFixed:
      return "rtk_fixed";
  }
  return "none";
}

std::string WhyNotAFix(const GnssFix& fix) {
  if (!fix.usable()) return "";
  if (const std::string why = WhyNotOnEarth(fix.position); !why.empty()) return why;
  if (!std::isfinite(fix.horizontal_accuracy_m) || fix.horizontal_accuracy_m <= 0.0 ||
      !std::isfinite(fix.vertical_accuracy_m) || fix.vertical_accuracy_m <= 0.0) {
    return "an accuracy is not a positive number of metres";
  }
  return "";
}

GnssTrack ReadGnssCsv(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw Error(path + ": cannot open the GNSS fixes");
  GnssTrack track;
  bool header_seen = false;
  std::string line;
  int line_number = 0;
  const auto fail = [&](const std::string& why) -> Error {
    return Error(Str() << path << ":" << line_number << ": " << why);
  };
  while (std::getline(in, line)) {
    ++line_number;
    const std::string text = Trimmed(line);
    if (text.empty()) continue;
    if (text[0] == '#') {
      const std::string comment = Trimmed(text.substr(1));
      if (comment.rfind("source:", 0) == 0) track.source = Trimmed(comment.substr(7));
      if (comment.rfind("ground_truth_enu_origin:", 0) == 0) {
        std::istringstream fields(comment.substr(24));
        GeodeticPoint origin;
        std::string rest;
        if (!(fields >> origin.latitude_deg >> origin.longitude_deg >> origin.height_m) || (fields >> rest)) {
          throw fail("ground_truth_enu_origin needs LATITUDE LONGITUDE HEIGHT");
        }
        if (const std::string why = WhyNotOnEarth(origin); !why.empty()) throw fail("ground_truth_enu_origin: " + why);
        track.ground_truth_enu_origin = origin;
      }
      continue;
    }
    if (!header_seen) {
      std::string header = text;
      header.erase(std::remove(header.begin(), header.end(), ' '), header.end());
      if (header != kHeader) throw fail(std::string("expected the header line \"") + kHeader + "\"");
      header_seen = true;
      continue;
    }
    const std::vector<std::string> fields = SplitFields(text);
    if (fields.size() != 7) throw fail(Str() << fields.size() << " fields where a fix has 7");
    GnssFix fix;
    if (!ParseTime(fields[0], &fix.t_ns)) throw fail("t_ns is not a time in nanoseconds: \"" + fields[0] + "\"");
    double* numbers[] = {&fix.position.latitude_deg, &fix.position.longitude_deg, &fix.position.height_m,
                         &fix.horizontal_accuracy_m, &fix.vertical_accuracy_m};
    for (int i = 0; i < 5; ++i) {
      if (!ParseNumber(fields[i + 1], numbers[i])) throw fail("field " + std::to_string(i + 2) + " is not a number");
    }
    const std::string type = Trimmed(fields[6]);
    bool known = false;
    for (GnssFixType t : kTypes) {
      if (type == GnssFixTypeName(t)) {
        fix.type = t;
        known = true;
      }
    }
    if (!known) throw fail("fix \"" + type + "\" is none of none, 2d, 3d, dgps, rtk_float, rtk_fixed");
    if (const std::string why = WhyNotAFix(fix); !why.empty()) throw fail(why);
    if (!track.fixes.empty() && fix.t_ns <= track.fixes.back().t_ns) throw fail("the fixes' times do not increase");
    track.fixes.push_back(fix);
  }
  if (!header_seen) throw Error(path + ": no header line; a GNSS file starts \"" + kHeader + "\"");
  return track;
}

void WriteGnssCsv(const std::string& path, const GnssTrack& track) {
  std::ostringstream out;
  if (!track.source.empty()) out << "# source: " << track.source << "\n";
  char line[256];
  if (track.ground_truth_enu_origin) {
    const GeodeticPoint& o = *track.ground_truth_enu_origin;
    std::snprintf(line, sizeof(line), "# ground_truth_enu_origin: %.9f %.9f %.4f\n", o.latitude_deg, o.longitude_deg,
                  o.height_m);
    out << line;
  }
  out << kHeader << "\n";
  for (const GnssFix& f : track.fixes) {
    std::snprintf(line, sizeof(line), "%lld,%.9f,%.9f,%.4f,%.3f,%.3f,%s\n", static_cast<long long>(f.t_ns),
                  f.position.latitude_deg, f.position.longitude_deg, f.position.height_m, f.horizontal_accuracy_m,
                  f.vertical_accuracy_m, GnssFixTypeName(f.type));
    out << line;
  }
  WriteFileAtomically(path, out.str());
}

std::vector<EnuFix> ToEnu(const std::vector<GnssFix>& fixes, const LocalTangentPlane& plane) {
  std::vector<EnuFix> enu;
  for (const GnssFix& f : fixes) {
    if (!f.usable()) continue;
    enu.push_back({f.t_ns, plane.ToEnu(f.position), f.horizontal_accuracy_m, f.vertical_accuracy_m});
  }
  return enu;
}

}  // namespace stitch
