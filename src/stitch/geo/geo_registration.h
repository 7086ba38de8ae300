#pragma once
// A map placed on Earth from the GNSS fixes taken while its frames were flown: the similarity
// (scale, rotation, translation) from the map's frame to the local ENU frame that puts its
// cameras' antennas where the fixes say, robust to fixes that jump.

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "stitch/geo/gnss_fix.h"
#include "stitch/geometry/rigid3.h"
#include "stitch/io/trajectory.h"

namespace stitch {

struct GeoReferenceOptions {
  bool enabled = true;         // place each map by the fixes where the run has them
  int min_fixes = 10;          // fixes within a map's frames needed to place it
  double min_spread_m = 10.0;  // the fixes' spread across their main direction for a free rotation
  // The camera's axis that points up in level flight, for maps whose fixes lie along a line: auto
  // (learned from the run's maps placed by their fixes alone, else -z), -z, -y or none.
  std::string camera_up_axis = "auto";
  double max_interpolation_gap_s = 1.0;  // a fix between two of the map's frames further apart is not used
  double outlier_chi2 = 14.16;           // a fix whose squared residual in its sigmas exceeds this is an outlier
  double min_inlier_fraction = 0.5;      // fixes that must agree with the placement
  double antenna_x_m = 0.0;              // the antenna in the camera's frame (x right, y down, z along the axis)
  double antenna_y_m = 0.0;
  double antenna_z_m = 0.0;
  double time_offset_s = 0.0;  // added to a fix's time to put it on the camera's clock
  // A map placed by its fixes is turned so that camera_up_axis (-z or -y, as set), averaged over
  // its cameras, points up: for a gimballed camera, whose tilt the fixes' heights barely say.
  // "true", "false", or "auto": true where the source states a gimbal's mount (stitch run
  // resolves it: SourceCameraUpAxis), false where nothing does (a service started alone).
  std::string level_by_camera = "auto";

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("enabled", enabled, "place every map on Earth by the aircraft's GNSS fixes where the run has them (gnss.csv)");
    v("min_fixes", min_fixes, "fixes within a map's frames needed to place it");
    v("min_spread_m", min_spread_m,
      "metres (and at least 5 of their horizontal sigmas) the fixes must spread across their main direction for "
      "the rotation to be taken from them alone; along a line the rotation about it is taken from camera_up_axis");
    v("camera_up_axis", camera_up_axis,
      "the camera's axis that points up in level flight, for maps whose fixes lie along a line: auto (as the run's "
      "maps placed by their fixes alone show it, the camera being mounted rigidly; else -z), -z (a nadir camera), "
      "-y (a forward-looking one) or none (such a map is not placed)");
    v("max_interpolation_gap_s", max_interpolation_gap_s,
      "a fix is matched to the camera's position interpolated between two of the map's frames at most this far apart");
    v("outlier_chi2", outlier_chi2,
      "a fix whose residual, squared in its stated sigmas and summed over the three axes, exceeds this is an outlier "
      "(14.16: what 99.7% of right fixes stay within, 3 sigma)");
    v("min_inlier_fraction", min_inlier_fraction, "fraction of a map's fixes that must agree with its placement");
    v("antenna_x_m", antenna_x_m, "the GNSS antenna's position in the camera's frame: x (right), metres");
    v("antenna_y_m", antenna_y_m, "the antenna's position in the camera's frame: y (down in the image), metres");
    v("antenna_z_m", antenna_z_m, "the antenna's position in the camera's frame: z (along the optical axis), metres");
    v("time_offset_s", time_offset_s, "seconds added to a fix's time to put it on the camera's clock");
    v("level_by_camera", level_by_camera,
      "true: turn each map its fixes place (not along a line) so that camera_up_axis, set to -z (a gimballed nadir "
      "camera) or -y, averaged over its cameras, points up: the fixes' heights (metres of noise) barely say a "
      "survey's tilt across its strips, a gimbal holds it to a fraction of a degree; false; auto: true, with "
      "camera_up_axis from the source, where the source states its camera's mount (the synthetic flight's nadir "
      "camera, a drone's photos whose XMP gives its gimbal straight down), else false");
  }
  bool Check(std::string* why) const;
  // level_by_camera resolved: "true" (auto counts as false: nothing stated the mount).
  bool LevelsByCamera() const { return level_by_camera == "true"; }
};

struct GeoPlacement {
  bool placed = false;
  // How the rotation was found: "gnss" (from the fixes alone), "gnss+camera-up" (the fixes lie
  // along a line; the rotation about it from the cameras' mean camera_up_axis) or
  // "gnss+learned-camera-up" (from the up direction the run's other maps showed).
  std::string method;
  std::string why_not;  // when not placed: what was missing, with the figures
  Sim3d enu_from_map;
  int fixes_matched = 0;  // fixes within the map's frames
  int inliers = 0;
  double horizontal_rms_m = 0.0;  // of the inliers' residuals
  double vertical_rms_m = 0.0;
  double spread_m = 0.0;  // the matched fixes' spread across their main direction
  // Placed by the fixes alone: ENU's up in the camera's frame, the mean over the matched fixes'
  // cameras, where they agree on it (a rigidly mounted camera that flew level). What the maps
  // along a line take with camera_up_axis auto.
  std::optional<Eigen::Vector3d> up_in_camera;
  // The outliers, grouped into spans of consecutive fixes: (first, last) time.
  std::vector<std::pair<int64_t, int64_t>> outlier_spans;
  // Fixes that agree with each other on another placement (at least a fifth of the fixes and
  // min_fixes): a receiver that jumped for good, or was spoofed. The map is held where the group
  // that came first puts it, unless the later one holds more than twice its fixes.
  struct Disagreement {
    int fixes = 0;
    int64_t first_ns = 0, last_ns = 0;  // the group's first and last fix
    double apart_m = 0.0;               // median distance between the cameras as the two placements put them
  };
  std::optional<Disagreement> disagreement;
};

// Places a map whose frames are `map_poses` (world_from_cam in the map's frame, any scale) by the
// fixes `fixes` (in one ENU frame). RANSAC over triples of fixes (pairs along a line), then least
// squares on the inliers (the antenna's offset applied once the rotation is known); deterministic.
// `learned_up_in_camera`: with camera_up_axis auto, the up direction in the camera's frame that
// other maps showed (else -z).
GeoPlacement PlaceByGnss(const Trajectory& map_poses, const std::vector<EnuFix>& fixes,
                         const GeoReferenceOptions& options,
                         const std::optional<Eigen::Vector3d>& learned_up_in_camera = std::nullopt);

// Places several maps of one run (each its poses and the fixes to place it by): with
// camera_up_axis auto, the maps along a line take the up direction that the run's maps placed by
// their fixes alone show, from the one with the most inliers.
struct MapToPlace {
  const Trajectory* poses = nullptr;
  const std::vector<EnuFix>* fixes = nullptr;
};
std::vector<GeoPlacement> PlaceMapsByGnss(const std::vector<MapToPlace>& maps, const GeoReferenceOptions& options);

}  // namespace stitch
