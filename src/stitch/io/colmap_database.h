#pragma once
// A sparse model as a COLMAP project database (colmap.github.io/database.html), so that COLMAP
// goes on from the SLAM map without extracting or matching features again (`colmap mapper
// --database_path database.db --image_path IMAGES --output_path OUT`, or the GUI's
// File > Import, or `point_triangulator` on the text model). It holds:
//
// - cameras: one per calibration of the model, with its focal length known (prior_focal_length);
// - images: their names and cameras, the SLAM pose as the prior pose;
// - keypoints: every feature of every image (x, y in COLMAP's pixel convention);
// - matches and two_view_geometries: for every pair of images that see points in common, the
//   features the map says are the same point, verified (config CALIBRATED, the pair's relative
//   pose, its essential and fundamental matrices).
//
// No descriptors: stitch's are 256-bit ORB, COLMAP's matchers read 128-byte SIFT; a table of ORB
// descriptors would mislead them rather than help.

#include <string>

#include "stitch/io/colmap_model.h"

namespace stitch {

struct ColmapDatabaseSummary {
  int cameras = 0;
  int images = 0;
  int keypoints = 0;
  int image_pairs = 0;  // pairs with matches
  int matches = 0;
};

// Writes `path` (a new file: an existing one is refused, COLMAP's own projects are not edited).
// Throws stitch::Error naming the file on any failure.
ColmapDatabaseSummary WriteColmapDatabase(const ColmapModel& model, const std::string& path);

}  // namespace stitch
