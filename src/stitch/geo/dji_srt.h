#pragma once
// The GNSS track a DJI aircraft writes beside each video: FILE.SRT, a SubRip subtitle per frame
// (or per second on older models) whose text holds the aircraft's position. Two layouts are read:
//
//   1
//   00:00:00,000 --> 00:00:00,033
//   <font size="28">FrameCnt: 1, DiffTime: 33ms
//   2023-04-08 16:36:41.395
//   [iso : 100] [shutter : 1/1000.0] ... [latitude: 47.368423] [longitude: 8.539054] [rel_alt: 1.200 abs_alt: 459.873]
//   </font>
//
// (Mavic, Air, Mini, FPV; `longtitude` as some firmware spells it, `[altitude: H]` on others),
// and the older `GPS(longitude,latitude,height)` (Phantom 4, Inspire; `BAROMETER:H` where
// given). A fix's time is its subtitle's start on the video's clock (the frames' times); blocks
// with no position (0, 0: no satellite lock) are left out, and the track is thinned to one fix
// per kDjiSrtMinIntervalNs (DJI writes its 5-10 Hz receiver's position at the frame rate).
// DJI states no accuracy: each fix gets kDjiSrtHorizontalAccuracyM / kDjiSrtVerticalAccuracyM.
// The heights are DJI's (abs_alt, altitude: above mean sea level, from the barometer and GNSS),
// marked so (GnssFix::height_above_msl): a dataset's track is raised to the ellipsoid by the
// geoid (geoid.h). The older layout's BAROMETER is the height above the take-off point, not
// marked: a map placed by it sits off vertically; its horizontal place and scale are not affected.

#include <cstdint>
#include <string>

#include "stitch/geo/gnss_fix.h"

namespace stitch {

inline constexpr double kDjiSrtHorizontalAccuracyM = 3.0;
inline constexpr double kDjiSrtVerticalAccuracyM = 10.0;
inline constexpr int64_t kDjiSrtMinIntervalNs = 100'000'000;  // 10 Hz

// Throws stitch::Error naming the file and line for a block without a SubRip time line, a
// position that is not a number or no place on Earth, or times that go backwards; and for a file
// with no position at all.
GnssTrack ReadDjiSrt(const std::string& path);

}  // namespace stitch
