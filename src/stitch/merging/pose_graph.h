#pragma once
// Sim3 pose-graph optimization over keyframes (as ORB-SLAM's essential graph): each keyframe has
// a similarity world_from_cam (its scale absorbs the monocular scale drift of its submap); edges
// are measured relative similarities, within a submap from its own keyframe poses and between
// submaps from verified connected frames. Ceres, 7 residuals per edge (rotation, translation,
// log scale), one keyframe per merged map held fixed.

#include <map>
#include <vector>

#include "stitch/geometry/rigid3.h"
#include "stitch/util/ids.h"

namespace stitch {

struct PoseGraphEdge {
  KeyframeId i, j;
  Sim3d i_from_j;  // camera j in camera i's frame
  double weight = 1.0;
  bool robust = false;  // Huber cost: for measurements that may be wrong (connected frames)
};

struct PoseGraphReport {
  int nodes = 0, edges = 0;
  double initial_cost = 0, final_cost = 0;
  bool converged = false;
};

// Optimizes `world_from_cam` of every keyframe in `poses` except those in `fixed`; edges naming a
// keyframe not in `poses` are ignored.
PoseGraphReport OptimizePoseGraph(std::map<KeyframeId, Sim3d>* poses, const std::vector<PoseGraphEdge>& edges,
                                  const std::vector<KeyframeId>& fixed, int iterations = 20);

}  // namespace stitch
