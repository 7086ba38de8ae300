#include "stitch/geo/geoid.h"

#include <cmath>

#include <proj.h>

#include "stitch/util/error.h"

namespace stitch {

struct Geoid::Proj {
  PJ_CONTEXT* context = nullptr;
  PJ* transformation = nullptr;
  ~Proj() {
    if (transformation) proj_destroy(transformation);
    if (context) proj_context_destroy(context);
  }
};

Geoid::Geoid(std::unique_ptr<Proj> proj) : proj_(std::move(proj)) {}
Geoid::Geoid(Geoid&&) noexcept = default;
Geoid& Geoid::operator=(Geoid&&) noexcept = default;
Geoid::~Geoid() = default;

Geoid Geoid::Egm96() {
  auto proj = std::make_unique<Proj>();
  proj->context = proj_context_create();
  if (!proj->context) throw Error("the geoid: PROJ could not start");
  proj_log_level(proj->context, PJ_LOG_NONE);  // its reasons come back as errors, not on stderr
  // Degrees in, the grid's height added to z (vgridshift's target = source + multiplier * N).
  proj->transformation = proj_create(proj->context,
                                     "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
                                     "+step +proj=vgridshift +grids=egm96_15.gtx +multiplier=1 "
                                     "+step +proj=unitconvert +xy_in=rad +xy_out=deg");
  if (!proj->transformation) {
    throw Error(std::string("the EGM96 geoid (PROJ's egm96_15.gtx) could not be opened: ") +
                proj_context_errno_string(proj->context, proj_context_errno(proj->context)) +
                " (Debian: install proj-data)");
  }
  return Geoid(std::move(proj));
}

double Geoid::HeightAboveEllipsoid(double latitude_deg, double longitude_deg) const {
  if (!(std::abs(latitude_deg) <= 90) || !(std::abs(longitude_deg) <= 180)) {
    throw Error("the geoid's height asked for no place on Earth");
  }
  const PJ_COORD at = proj_trans(proj_->transformation, PJ_FWD, proj_coord(longitude_deg, latitude_deg, 0, 0));
  if (!std::isfinite(at.xyz.z)) {  // PROJ's HUGE_VAL where it has no grid
    const int error = proj_errno(proj_->transformation);
    proj_errno_reset(proj_->transformation);
    throw Error(std::string("the geoid's height at that place: ") + proj_context_errno_string(proj_->context, error));
  }
  return at.xyz.z;
}

std::string MslToEllipsoid::Raise(std::vector<GnssFix>* fixes) {
  bool any = false;
  for (const GnssFix& fix : *fixes) any = any || (fix.height_above_msl && fix.usable());
  if (!any) return "";
  if (!opened_) {
    opened_ = true;
    try {
      geoid_.emplace(Geoid::Egm96());
    } catch (const Error& e) {
      return e.what();
    }
  }
  if (!geoid_) return "";
  try {
    std::vector<double> undulation(fixes->size(), 0.0);  // all found before any fix changes
    for (size_t i = 0; i < fixes->size(); ++i) {
      const GnssFix& fix = (*fixes)[i];
      if (fix.height_above_msl && fix.usable()) {
        undulation[i] = geoid_->HeightAboveEllipsoid(fix.position.latitude_deg, fix.position.longitude_deg);
      }
    }
    for (size_t i = 0; i < fixes->size(); ++i) {
      GnssFix& fix = (*fixes)[i];
      if (!fix.height_above_msl || !fix.usable()) continue;
      fix.position.height_m += undulation[i];
      fix.height_above_msl = false;
    }
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

std::string HeightsAboveEllipsoid(std::vector<GnssFix>* fixes) {
  return MslToEllipsoid().Raise(fixes);
}

}  // namespace stitch
