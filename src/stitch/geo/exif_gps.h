#pragma once
// GNSS fixes from the photos of an image folder: the EXIF GPS tags a survey camera or a drone
// writes into each photo (GPSLatitude/Ref, GPSLongitude/Ref, GPSAltitude/Ref), read with exiv2.
// Each photo's fix is at that photo's frame time, so no clock needs aligning. EXIF's altitude is
// above mean sea level (as DJI's), marked so: the track is raised to the ellipsoid (geoid.h). The
// accuracy: GPSHPositioningError where the camera writes it (EXIF 2.31), DJI's RTK standard
// deviations (Xmp.drone-dji.RtkStdLat/Lon/Hgt, with an RTK fix type) where it writes them, else
// kExifHorizontalAccuracyM / kExifVerticalAccuracyM. Photos without GPS tags give no fix.

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "stitch/geo/gnss_fix.h"
#include "stitch/io/image_sequence.h"

namespace stitch {

inline constexpr double kExifHorizontalAccuracyM = 5.0;
inline constexpr double kExifVerticalAccuracyM = 10.0;

// The fix `image_path`'s tags state (t_ns 0), or none with `why` (no GPS tags, tags that are no
// place on Earth, a file exiv2 cannot read). Never throws.
std::optional<GnssFix> ReadExifGps(const std::string& image_path, std::string* why);

// The gimbal's pitch a drone wrote into the photo's XMP (DJI: Xmp.drone-dji.GimbalPitchDegree,
// degrees, -90 straight down, 0 at the horizon); none where the photo has none or cannot be read.
// Never throws.
std::optional<double> ReadGimbalPitchDeg(const std::string& image_path);

// Whether the photos state a camera looking straight down: of the first `photos` of `images`,
// each that states a gimbal pitch states one within `tolerance_deg` of -90, and at least one
// does (a survey mission's nadir gimbal); what a folder's source states as its camera's up axis
// (-z).
bool PhotosStateANadirGimbal(const std::vector<ImageEntry>& images, int photos = 5, double tolerance_deg = 1.0);

// The fixes of `images` (FolderImageTimes), each at its image's time; its `source`
// says how many photos gave none, and why for the first. No photo with a fix: an empty track.
GnssTrack ExifGnssTrack(const std::vector<ImageEntry>& images);

}  // namespace stitch
