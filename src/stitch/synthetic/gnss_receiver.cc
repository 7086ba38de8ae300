#include "stitch/synthetic/gnss_receiver.h"

#include <cmath>
#include <sstream>

#include "stitch/util/error.h"
#include "stitch/util/options.h"
#include "stitch/util/rng.h"

namespace stitch {

namespace {

struct Span {
  double start_s = 0, length_s = 0, metres = 0;
  bool Holds(double t_s) const { return t_s >= start_s && t_s < start_s + length_s; }
};

// "A:B[:C],..." with `fields` numbers each (2 or 3); false with `why` for anything else.
bool ParseSpans(const std::string& text, int fields, std::vector<Span>* spans, std::string* why) {
  spans->clear();
  std::istringstream list(text);
  std::string item;
  while (std::getline(list, item, ',')) {
    std::istringstream parts(item);
    std::string part;
    std::vector<double> values;
    while (std::getline(parts, part, ':')) {
      char* end = nullptr;
      const double value = std::strtod(part.c_str(), &end);
      if (part.empty() || end != part.c_str() + part.size() || !std::isfinite(value)) {
        return *why = "\"" + item + "\" is not " + (fields == 2 ? "START_S:LENGTH_S" : "START_S:LENGTH_S:METRES"),
               false;
      }
      values.push_back(value);
    }
    if (static_cast<int>(values.size()) != fields || values[0] < 0 || values[1] <= 0) {
      return *why = "\"" + item + "\" is not " + (fields == 2 ? "START_S:LENGTH_S" : "START_S:LENGTH_S:METRES") +
                    " with a positive length",
             false;
    }
    spans->push_back({values[0], values[1], fields == 3 ? values[2] : 0.0});
  }
  return true;
}

}  // namespace

bool GnssReceiverOptions::Check(std::string* why) const {
  if (!(rate_hz >= 0 && rate_hz <= 100)) return *why = "rate_hz must be in [0, 100]", false;
  if (!(horizontal_noise_m > 0 && vertical_noise_m > 0)) return *why = "the noise must be positive", false;
  if (const std::string off = WhyNotOnEarth({origin_latitude_deg, origin_longitude_deg, origin_height_m});
      !off.empty()) {
    return *why = "the origin is no place on Earth: " + off, false;
  }
  std::vector<Span> spans;
  std::string bad;
  if (!ParseSpans(dropouts, 2, &spans, &bad)) return *why = "dropouts: " + bad, false;
  if (!ParseSpans(jumps, 3, &spans, &bad)) return *why = "jumps: " + bad, false;
  if (!std::isfinite(offset_m) || !(offset_from_s >= 0))
    return *why = "offset_m and offset_from_s must be finite, offset_from_s not negative", false;
  return true;
}

GnssTrack SimulateGnssReceiver(const Trajectory& ground_truth, const GnssReceiverOptions& options, uint64_t seed) {
  CheckOptions(options, "synthetic.gnss");
  GnssTrack track;
  const GeodeticPoint origin{options.origin_latitude_deg, options.origin_longitude_deg, options.origin_height_m};
  track.ground_truth_enu_origin = origin;
  char source[160];
  std::snprintf(source, sizeof(source), "synthetic receiver (%g Hz, %g m horizontal and %g m vertical noise)",
                options.rate_hz, options.horizontal_noise_m, options.vertical_noise_m);
  track.source = source;
  if (options.rate_hz <= 0 || ground_truth.size() < 2) return track;
  std::vector<Span> dropouts, jumps;
  std::string unused;
  ParseSpans(options.dropouts, 2, &dropouts, &unused);
  ParseSpans(options.jumps, 3, &jumps, &unused);
  const LocalTangentPlane plane(origin);
  const int64_t first = ground_truth.poses().front().t_ns, last = ground_truth.poses().back().t_ns;
  // Fixes on the flight's clock (every period from 0 s), each with noise of its own: any span of
  // the flight has the same fixes as the whole flight over that span.
  const double period_ns = 1e9 / options.rate_hz;
  for (auto k = static_cast<int64_t>(std::ceil(first / period_ns));; ++k) {
    const auto t_ns = static_cast<int64_t>(std::llround(k * period_ns));
    if (t_ns > last) break;
    if (t_ns < first) continue;
    const double t_s = t_ns * 1e-9;
    Rng rng(HashU64(seed, 0x67AA55ULL, static_cast<uint64_t>(k)));
    const Eigen::Vector3d noise(rng.Normal(0.0, options.horizontal_noise_m),
                                rng.Normal(0.0, options.horizontal_noise_m), rng.Normal(0.0, options.vertical_noise_m));
    bool dropped = false;
    for (const Span& d : dropouts) dropped = dropped || d.Holds(t_s);
    const std::optional<Rigid3d> pose = ground_truth.PoseAt(t_ns, 10 * static_cast<int64_t>(period_ns));
    if (dropped || !pose) continue;
    Eigen::Vector3d enu = pose->translation + noise;
    for (const Span& j : jumps) {
      if (j.Holds(t_s)) enu.y() += j.metres;
    }
    if (options.offset_m != 0.0 && t_s >= options.offset_from_s) enu.x() += options.offset_m;
    GnssFix fix;
    fix.t_ns = t_ns;
    fix.position = plane.ToGeodetic(enu);
    fix.horizontal_accuracy_m = options.horizontal_noise_m;
    fix.vertical_accuracy_m = options.vertical_noise_m;
    fix.type = GnssFixType::k3d;
    track.fixes.push_back(fix);
  }
  return track;
}

}  // namespace stitch
