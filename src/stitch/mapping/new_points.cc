#include "stitch/mapping/new_points.h"

#include <set>

#include "stitch/estimators/triangulation.h"
#include "stitch/map/matcher.h"

namespace stitch {

std::vector<MapPointId> TriangulateNewPoints(Map* map, KeyframeId keyframe, const ViewGeometry& geometry,
                                             int neighbours, double min_baseline_ratio) {
  const PinholeIntrinsics& k = geometry.intrinsics;
  const ScalePyramid& pyramid = geometry.pyramid;
  Keyframe* kf1 = map->FindKeyframe(keyframe);
  const std::vector<KeyframeId> covisible = map->BestCovisible(keyframe, neighbours);
  const double ratio_factor = 1.5 * pyramid.scale_factor;
  std::vector<MapPointId> created;
  for (KeyframeId neighbour : covisible) {
    Keyframe* kf2 = map->FindKeyframe(neighbour);
    if (!kf2) continue;
    const double baseline = (kf1->Centre() - kf2->Centre()).norm();
    const double median_depth = map->MedianDepth(neighbour);
    if (median_depth <= 0 || baseline / median_depth < min_baseline_ratio) continue;
    const Eigen::Matrix3d f21 = FundamentalMatrix(kf1->cam_from_world, kf2->cam_from_world, k);
    const auto pairs = SearchForTriangulation(*kf1, *kf2, f21, k, pyramid);
    const Eigen::Matrix3d r1 = kf1->cam_from_world.RotationMatrix().transpose();
    const Eigen::Matrix3d r2 = kf2->cam_from_world.RotationMatrix().transpose();
    for (const auto& [i, j] : pairs) {
      if (kf1->points[i].valid() || kf2->points[j].valid()) continue;
      const Eigen::Vector2d n1 = k.Normalize(kf1->undistorted[i]);
      const Eigen::Vector2d n2 = k.Normalize(kf2->undistorted[j]);
      const Eigen::Vector3d ray1 = r1 * n1.homogeneous(), ray2 = r2 * n2.homogeneous();
      const double cos_rays = ray1.dot(ray2) / (ray1.norm() * ray2.norm());
      if (cos_rays <= 0 || cos_rays >= 0.9998) continue;
      const auto x = TriangulateDlt(kf1->cam_from_world, n1, kf2->cam_from_world, n2);
      if (!x) continue;
      const Eigen::Vector3d in1 = kf1->cam_from_world * *x, in2 = kf2->cam_from_world * *x;
      if (in1.z() <= 0 || in2.z() <= 0) continue;
      const int level1 = kf1->keypoints[i].octave, level2 = kf2->keypoints[j].octave;
      if ((k.Project(in1) - kf1->undistorted[i]).squaredNorm() > 5.991 * pyramid.sigma2[level1]) continue;
      if ((k.Project(in2) - kf2->undistorted[j]).squaredNorm() > 5.991 * pyramid.sigma2[level2]) continue;
      // Scale consistency: the distance ratio must agree with the pyramid levels seen at.
      const double distance1 = (*x - kf1->Centre()).norm(), distance2 = (*x - kf2->Centre()).norm();
      if (distance1 <= 0 || distance2 <= 0) continue;
      const double ratio_distance = distance2 / distance1;
      const double ratio_octave = pyramid.scale[level1] / pyramid.scale[level2];
      if (ratio_distance * ratio_factor < ratio_octave || ratio_distance > ratio_octave * ratio_factor) continue;
      MapPoint point;
      point.id = map->NewPointId();
      point.position = *x;
      point.reference_keyframe = keyframe;
      point.first_keyframe = keyframe;
      map->AddPoint(point);
      map->AddObservation(keyframe, i, point.id);
      map->AddObservation(neighbour, j, point.id);
      map->UpdatePointAppearance(point.id);
      map->UpdatePointGeometry(point.id);
      created.push_back(point.id);
    }
  }
  return created;
}

int FuseWithNeighbours(Map* map, KeyframeId keyframe, const ViewGeometry& geometry, int neighbours) {
  // First and second order neighbours.
  std::vector<KeyframeId> targets;
  std::set<KeyframeId> seen{keyframe};
  for (KeyframeId n : map->BestCovisible(keyframe, neighbours)) {
    if (seen.insert(n).second) targets.push_back(n);
  }
  const size_t first_order = targets.size();
  for (size_t t = 0; t < first_order; ++t) {
    for (KeyframeId n2 : map->BestCovisible(targets[t], 5)) {
      if (seen.insert(n2).second) targets.push_back(n2);
    }
  }
  int fused = 0;
  // The keyframe's points into the neighbours...
  std::vector<MapPointId> own;
  for (MapPointId p : map->FindKeyframe(keyframe)->points) {
    if (p.valid()) own.push_back(p);
  }
  for (KeyframeId target : targets) fused += Fuse(map, target, own, geometry.intrinsics);
  // ...and the neighbours' points into the keyframe.
  std::set<MapPointId> theirs;
  for (KeyframeId target : targets) {
    if (const Keyframe* kf = map->FindKeyframe(target)) {
      for (MapPointId p : kf->points) {
        if (p.valid()) theirs.insert(p);
      }
    }
  }
  fused += Fuse(map, keyframe, std::vector<MapPointId>(theirs.begin(), theirs.end()), geometry.intrinsics);
  for (MapPointId p : map->FindKeyframe(keyframe)->points) {
    if (!p.valid() || !map->FindPoint(p)) continue;
    map->UpdatePointAppearance(p);
    map->UpdatePointGeometry(p);
  }
  map->UpdateConnections(keyframe);
  return fused;
}

}  // namespace stitch
