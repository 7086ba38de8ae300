#include "stitch/geo/dji_srt.h"

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <optional>
#include <regex>

#include "stitch/util/error.h"

namespace stitch {
namespace {

// A number, the whole of `text` but blanks around it; nullopt otherwise.
std::optional<double> Number(const std::string& text) {
  const size_t first = text.find_first_not_of(" \t");
  if (first == std::string::npos) return std::nullopt;
  const char* begin = text.c_str() + first;
  char* end = nullptr;
  errno = 0;
  const double value = std::strtod(begin, &end);
  if (end == begin || errno == ERANGE || !std::isfinite(value)) return std::nullopt;
  while (*end == ' ' || *end == '\t') ++end;
  if (*end != '\0') return std::nullopt;
  return value;
}

// One subtitle: where its time line is, when it starts, and its text without markup.
struct Subtitle {
  int line = 0;
  int64_t t_ns = 0;
  std::string text;
};

}  // namespace

GnssTrack ReadDjiSrt(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(path + ": cannot be read");
  const std::string name = std::filesystem::path(path).filename().string();
  const auto fail = [&](int line, const std::string& what) {
    throw Error(path + ":" + std::to_string(line) + ": " + what);
  };
  static const std::regex kTimeLine(R"(^\s*(\d+):(\d{2}):(\d{2})[,.](\d{3})\s*-->\s*\d+:\d{2}:\d{2}[,.]\d{3}\s*$)");
  static const std::regex kMarkup("<[^>]*>");
  static const std::regex kLatitude(R"(\[\s*latitude\s*:([^\]]*)\])");
  static const std::regex kLongitude(R"(\[\s*longt?itude\s*:([^\]]*)\])");
  static const std::regex kAbsoluteAltitude(R"(abs_alt\s*:\s*([^\s\]]*))");
  static const std::regex kAltitude(R"(\[\s*altitude\s*:([^\]]*)\])");
  static const std::regex kOldGps(R"(GPS\s*\(([^,)]*),([^,)]*)(?:,([^,)]*))?\))");
  static const std::regex kBarometer(R"(BAROMETER\s*:\s*([^\s\]]*))");

  // The subtitles: blocks between blank lines, each an index, a time line and text.
  std::vector<Subtitle> subtitles;
  std::string line;
  int number = 0;
  std::optional<Subtitle> open;
  bool in_block = false;
  while (std::getline(in, line)) {
    ++number;
    if (number == 1 && line.rfind("\xEF\xBB\xBF", 0) == 0) line.erase(0, 3);  // a byte-order mark
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.find_first_not_of(" \t") == std::string::npos) {
      if (open) subtitles.push_back(std::move(*open));
      open.reset();
      in_block = false;
      continue;
    }
    std::smatch time;
    if (!open && std::regex_match(line, time, kTimeLine)) {
      const int64_t ms =
          ((std::stoll(time[1]) * 60 + std::stoll(time[2])) * 60 + std::stoll(time[3])) * 1000 + std::stoll(time[4]);
      if (ms > 1'000'000'000'000LL) fail(number, "a subtitle time beyond any flight");
      open = Subtitle{number, ms * 1'000'000, ""};
      in_block = true;
      continue;
    }
    if (open) {
      open->text += std::regex_replace(line, kMarkup, " ") + "\n";
    } else if (!in_block) {
      // The block's index (a number); anything else before a time line is not SubRip.
      if (!Number(line)) fail(number, "not a DJI SRT subtitle (expected its number, then its time line)");
      in_block = true;
    } else {
      fail(number, "a subtitle without its time line (HH:MM:SS,mmm --> HH:MM:SS,mmm)");
    }
  }
  if (open) subtitles.push_back(std::move(*open));

  GnssTrack track;
  track.source = "DJI SRT " + name;
  int64_t last_ns = -1, kept_ns = -1;
  for (const Subtitle& s : subtitles) {
    const auto field = [&](const std::regex& pattern, int group = 1) -> std::optional<std::string> {
      std::smatch match;
      if (!std::regex_search(s.text, match, pattern) || !match[group].matched) return std::nullopt;
      return match[group].str();
    };
    const auto number_of = [&](const std::optional<std::string>& text, const char* what) -> std::optional<double> {
      if (!text) return std::nullopt;
      const std::optional<double> value = Number(*text);
      if (!value) fail(s.line, std::string(what) + " is not a number: '" + *text + "'");
      return value;
    };
    std::optional<double> latitude = number_of(field(kLatitude), "the latitude");
    std::optional<double> longitude = number_of(field(kLongitude), "the longitude");
    std::optional<double> height = number_of(field(kAbsoluteAltitude), "abs_alt");
    if (!height) height = number_of(field(kAltitude), "the altitude");
    const bool above_sea_level = height.has_value();  // the older layout's heights are the barometer's
    if (!latitude && !longitude) {                    // the older layout: GPS(longitude,latitude,height)
      longitude = number_of(field(kOldGps, 1), "GPS()'s longitude");
      latitude = number_of(field(kOldGps, 2), "GPS()'s latitude");
      if (!height) height = number_of(field(kBarometer), "BAROMETER");
      if (!height) height = number_of(field(kOldGps, 3), "GPS()'s height");
    }
    if (!latitude && !longitude) continue;  // a subtitle without a position
    if (!latitude || !longitude) fail(s.line, "a latitude without a longitude, or the other way round");
    if (*latitude == 0 && *longitude == 0) continue;  // no satellite lock
    if (s.t_ns < last_ns) fail(s.line, "its time goes back from the subtitle before");
    last_ns = s.t_ns;
    if (kept_ns >= 0 && s.t_ns - kept_ns < kDjiSrtMinIntervalNs) continue;
    GnssFix fix;
    fix.t_ns = s.t_ns;
    fix.position = {*latitude, *longitude, height.value_or(0.0)};
    fix.horizontal_accuracy_m = kDjiSrtHorizontalAccuracyM;
    fix.vertical_accuracy_m = height ? kDjiSrtVerticalAccuracyM : 1000.0;  // no height: a free one
    fix.height_above_msl = above_sea_level;
    fix.type = GnssFixType::k3d;
    if (const std::string why = WhyNotAFix(fix); !why.empty()) fail(s.line, why);
    track.fixes.push_back(fix);
    kept_ns = s.t_ns;
  }
  if (track.fixes.empty())
    throw Error(path + ": no position in any of its " + std::to_string(subtitles.size()) +
                " subtitles (a DJI SRT without GNSS, or not one)");
  return track;
}

}  // namespace stitch
