#pragma once
// What of a map goes into the files users open (map.ply): points a viewer's "zoom to fit" and a
// photogrammetry tool can take as they are. A sparse SLAM map holds a few points triangulated from
// nearly parallel rays, hundreds or thousands of times farther out than the scene; they are kept
// in the map (tracking may still use them) and left out of the export.

#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "stitch/geometry/camera.h"
#include "stitch/io/colmap_model.h"
#include "stitch/map/map.h"

namespace stitch {

struct MapExportOptions {
  int min_observations = 2;  // keyframes that must see a point
  double max_extent_ratio =
      10;  // a point farther from the scene's centre than this many times the scene's extent is out

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("min_observations", min_observations, "keyframes that must see a point for it to be exported");
    v("max_extent_ratio", max_extent_ratio,
      "a point farther from the scene's centre (the points' median) than this many times the scene's extent (the "
      "90th percentile of the points' distances from that centre) is left out of the export");
  }
  bool Check(std::string* why) const;
};

// Which points to export, one flag per point (positions and their observation counts in the same
// order). The scene's centre and extent are measured on the points seen often enough.
std::vector<bool> PointsToExport(const std::vector<Eigen::Vector3d>& positions, const std::vector<int>& observations,
                                 const MapExportOptions& options);

// The map as a COLMAP sparse model: every keyframe an image (its pose, its features where they
// were detected, in the distorted image its camera describes), every point PointsToExport keeps
// with its observations as its track (ids renumbered from 1; points seen by fewer than two
// images left out), each point's mean reprojection error set. `camera_of` gives each keyframe's
// camera (one model camera per distinct calibration, ids from 1 in the order first met; a
// keyframe without one is left out), `name` its image name.
ColmapModel ColmapModelOf(const Map& map, const std::function<const Camera*(const Keyframe&)>& camera_of,
                          const MapExportOptions& options, const std::function<std::string(const Keyframe&)>& name);

}  // namespace stitch
