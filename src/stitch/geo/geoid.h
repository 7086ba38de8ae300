#pragma once
// Heights above mean sea level to heights above the WGS84 ellipsoid. DJI's SRT and EXIF tracks,
// MAVLink's GLOBAL_POSITION_INT and MAVLink 1's GPS_RAW_INT state altitudes above mean sea level
// (the EGM96 geoid, as receivers report it); stitch's fixes carry heights above the ellipsoid
// (gnss_fix.h). The two differ by the geoid's height N at the place, -107 to +85 m over the
// Earth (about +46 m in Bavaria): h = H + N. N is interpolated from EGM96 on its 15 arc-minute
// grid, the file Debian's proj-data installs (egm96_15.gtx), through PROJ (libproj), as
// `cs2cs EPSG:4326+5773 EPSG:4979` would.

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "stitch/geo/gnss_fix.h"

namespace stitch {

class Geoid {
 public:
  // EGM96 from PROJ's data. Throws stitch::Error saying what to install when PROJ cannot open
  // the grid (Debian: proj-data).
  static Geoid Egm96();

  Geoid(Geoid&&) noexcept;
  Geoid& operator=(Geoid&&) noexcept;
  ~Geoid();

  // The geoid's height above the ellipsoid at a place, metres. Throws stitch::Error for a place
  // the grid does not cover (no place on Earth).
  double HeightAboveEllipsoid(double latitude_deg, double longitude_deg) const;

 private:
  struct Proj;
  explicit Geoid(std::unique_ptr<Proj> proj);
  std::unique_ptr<Proj> proj_;  // PROJ's context and transformation: one owner thread
};

// Raises fixes whose heights are above mean sea level (GnssFix::height_above_msl) to the
// ellipsoid by EGM96, opening the geoid when first needed. Where it cannot be had (no grid), the
// fixes stay as they are (the map then sits the geoid's height off vertically). One owner thread.
class MslToEllipsoid {
 public:
  // Why fixes above mean sea level stay so: said by the first call that meets such a fix and
  // cannot raise it, empty otherwise (and after).
  std::string Raise(std::vector<GnssFix>* fixes);

 private:
  std::optional<Geoid> geoid_;
  bool opened_ = false;
};

// A track's fixes raised at once (MslToEllipsoid); why not where they stay above mean sea level.
std::string HeightsAboveEllipsoid(std::vector<GnssFix>* fixes);

}  // namespace stitch
