#include "stitch/geo/exif_gps.h"

#include <cmath>

#include "stitch/geo/exiv2.h"

namespace stitch {
namespace {

STITCH_EXIV2_BEGIN

// Degrees from EXIF's three rationals (degrees, minutes, seconds); NaN when they are not three
// finite rationals.
double Degrees(const Exiv2::Exifdatum& datum) {
  if (datum.count() != 3) return NAN;
  double degrees = 0, unit = 1;
  for (long i = 0; i < 3; ++i, unit *= 60) {
    const Exiv2::Rational r = datum.toRational(i);
    if (r.second == 0) return NAN;
    degrees += static_cast<double>(r.first) / r.second / unit;
  }
  return degrees;
}

const Exiv2::Exifdatum* Find(const Exiv2::ExifData& exif, const char* key) {
  const auto found = exif.findKey(Exiv2::ExifKey(key));
  return found == exif.end() ? nullptr : &*found;
}

// A number in the photo's XMP, by its key's text (a key exiv2 does not know, as DJI's, is compared
// as text: looking it up by an XmpKey throws for a namespace not registered); NaN where absent.
double XmpNumber(const Exiv2::XmpData& xmp, const std::string& key) {
  for (const Exiv2::Xmpdatum& datum : xmp) {
    if (datum.key() != key) continue;
    try {
      return std::stod(datum.toString());
    } catch (...) {
      return NAN;
    }
  }
  return NAN;
}

std::optional<GnssFix> ReadTags(const std::string& path, std::string* why) {
  Exiv2::Image::AutoPtr image = Exiv2::ImageFactory::open(path);
  image->readMetadata();
  const Exiv2::ExifData& exif = image->exifData();
  const Exiv2::Exifdatum* latitude = Find(exif, "Exif.GPSInfo.GPSLatitude");
  const Exiv2::Exifdatum* longitude = Find(exif, "Exif.GPSInfo.GPSLongitude");
  if (!latitude || !longitude) {
    *why = "no GPS position in its EXIF tags";
    return std::nullopt;
  }
  GnssFix fix;
  fix.position.latitude_deg = Degrees(*latitude);
  fix.position.longitude_deg = Degrees(*longitude);
  const Exiv2::Exifdatum* latitude_ref = Find(exif, "Exif.GPSInfo.GPSLatitudeRef");
  const Exiv2::Exifdatum* longitude_ref = Find(exif, "Exif.GPSInfo.GPSLongitudeRef");
  if (latitude_ref && latitude_ref->toString() == "S") fix.position.latitude_deg = -fix.position.latitude_deg;
  if (longitude_ref && longitude_ref->toString() == "W") fix.position.longitude_deg = -fix.position.longitude_deg;
  if (const Exiv2::Exifdatum* altitude = Find(exif, "Exif.GPSInfo.GPSAltitude"); altitude && altitude->count() == 1) {
    const Exiv2::Rational r = altitude->toRational(0);
    fix.position.height_m = r.second != 0 ? static_cast<double>(r.first) / r.second : 0.0;
    const Exiv2::Exifdatum* below = Find(exif, "Exif.GPSInfo.GPSAltitudeRef");
    if (below && below->count() == 1 && below->toLong(0) == 1) fix.position.height_m = -fix.position.height_m;
    fix.height_above_msl = true;  // EXIF: "the altitude based on the reference" of sea level
  }
  fix.horizontal_accuracy_m = kExifHorizontalAccuracyM;
  fix.vertical_accuracy_m = kExifVerticalAccuracyM;
  fix.type = GnssFixType::k3d;
  if (const Exiv2::Exifdatum* error = Find(exif, "Exif.GPSInfo.GPSHPositioningError"); error && error->count() == 1) {
    const Exiv2::Rational r = error->toRational(0);
    if (r.second != 0 && r.first > 0) fix.horizontal_accuracy_m = static_cast<double>(r.first) / r.second;
  }
  // DJI's RTK models write the solution's standard deviations in their XMP.
  const Exiv2::XmpData& xmp = image->xmpData();
  const double rtk_lat = XmpNumber(xmp, "Xmp.drone-dji.RtkStdLat"), rtk_lon = XmpNumber(xmp, "Xmp.drone-dji.RtkStdLon"),
               rtk_height = XmpNumber(xmp, "Xmp.drone-dji.RtkStdHgt");
  if (rtk_lat > 0 && rtk_lon > 0 && rtk_height > 0) {
    fix.horizontal_accuracy_m = std::max(rtk_lat, rtk_lon);
    fix.vertical_accuracy_m = rtk_height;
    fix.type = GnssFixType::kRtkFixed;
  }
  if (!std::isfinite(fix.position.latitude_deg) || !std::isfinite(fix.position.longitude_deg)) {
    *why = "GPS tags that are not three rationals";
    return std::nullopt;
  }
  if (fix.position.latitude_deg == 0 && fix.position.longitude_deg == 0) {
    *why = "GPS position 0, 0 (no lock)";
    return std::nullopt;
  }
  if (const std::string wrong = WhyNotAFix(fix); !wrong.empty()) {
    *why = "GPS tags: " + wrong;
    return std::nullopt;
  }
  return fix;
}

STITCH_EXIV2_END

}  // namespace

std::optional<GnssFix> ReadExifGps(const std::string& image_path, std::string* why) {
  std::string ignored;
  if (!why) why = &ignored;
  try {
    return ReadTags(image_path, why);
  } catch (const std::exception& e) {  // Exiv2::AnyError, and what a damaged file makes it throw
    *why = std::string("its metadata cannot be read: ") + e.what();
    return std::nullopt;
  }
}

std::optional<double> ReadGimbalPitchDeg(const std::string& image_path) {
  try {
    STITCH_EXIV2_BEGIN
    Exiv2::Image::AutoPtr image = Exiv2::ImageFactory::open(image_path);
    STITCH_EXIV2_END
    image->readMetadata();
    const double pitch = XmpNumber(image->xmpData(), "Xmp.drone-dji.GimbalPitchDegree");
    if (!std::isfinite(pitch) || pitch < -180 || pitch > 180) return std::nullopt;
    return pitch;
  } catch (const std::exception&) {  // Exiv2::AnyError, and what a damaged file makes it throw
    return std::nullopt;
  }
}

bool PhotosStateANadirGimbal(const std::vector<ImageEntry>& images, int photos, double tolerance_deg) {
  int stated = 0;
  for (size_t i = 0; i < images.size() && i < static_cast<size_t>(photos); ++i) {
    const std::optional<double> pitch = ReadGimbalPitchDeg(images[i].path);
    if (!pitch) continue;
    if (std::abs(*pitch + 90.0) > tolerance_deg) return false;
    ++stated;
  }
  return stated > 0;
}

GnssTrack ExifGnssTrack(const std::vector<ImageEntry>& images) {
  GnssTrack track;
  int without = 0;
  std::string first_why, first_without;
  for (const auto& [t_ns, path] : images) {
    std::string why;
    std::optional<GnssFix> fix = ReadExifGps(path, &why);
    if (!fix) {
      if (++without == 1) {
        first_why = why;
        first_without = path;
      }
      continue;
    }
    if (!track.fixes.empty() && t_ns <= track.fixes.back().t_ns) continue;  // two photos at one time
    fix->t_ns = t_ns;
    track.fixes.push_back(*fix);
  }
  if (track.fixes.empty()) return {};
  track.source = "EXIF GPS tags of " + std::to_string(track.fixes.size()) + " photos";
  if (without > 0) {
    track.source +=
        " (" + std::to_string(without) + " without a fix, the first " + first_without + ": " + first_why + ")";
  }
  return track;
}

}  // namespace stitch
