#pragma once
// A submap: keyframes, map points, their observations and the covisibility graph. One owner
// (the mapper's or the tracker's thread); not thread-safe. Keyframes and points are values in
// hash maps, referenced by id; pointers returned by Find* stay valid until that element is
// removed (unordered_map keeps element addresses stable).

#include <map>
#include <set>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "stitch/features/descriptor.h"
#include "stitch/map/frame.h"

namespace stitch {

struct Keyframe {
  KeyframeId id;
  int frame_index = -1;
  int64_t t_ns = 0;
  Rigid3d cam_from_world;  // world = the submap's frame
  std::vector<cv::KeyPoint> keypoints;
  std::vector<Eigen::Vector2d> undistorted;
  cv::Mat descriptors;
  BowVector bow;
  FeatureVector bow_features;
  FeatureGrid grid;
  std::vector<MapPointId> points;  // per feature

  // Maintained by Map:
  std::map<KeyframeId, int> covisibility;           // shared points, every keyframe sharing any
  std::vector<std::pair<int, KeyframeId>> ordered;  // covisible with weight >= 15 (or the best), heaviest first
  KeyframeId parent;                                // spanning tree
  std::set<KeyframeId> children;

  Eigen::Vector3d Centre() const { return cam_from_world.CentreInWorld(); }
  int CountPoints() const;
};

struct MapPoint {
  MapPointId id;
  Eigen::Vector3d position = Eigen::Vector3d::Zero();  // point_in_world (submap frame)
  Descriptor descriptor{};
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();  // mean viewing direction, unit
  float min_distance = 0, max_distance = 0;          // scale-invariance range
  std::map<KeyframeId, int> observations;            // keyframe -> feature index
  KeyframeId reference_keyframe;
  KeyframeId first_keyframe;
  int visible = 1;  // times predicted in view
  int found = 1;    // times matched when predicted
  double FoundRatio() const { return static_cast<double>(found) / std::max(1, visible); }
};

class Map {
 public:
  // Points this map creates get indices from `first_point_index` up (the tracker's initial
  // points and the mapper's triangulated ones must not share indices).
  Map(SubmapId id, ScalePyramid pyramid, uint32_t first_point_index = 0);

  SubmapId id() const { return id_; }
  const ScalePyramid& pyramid() const { return pyramid_; }

  // --- keyframes
  // Inserts a keyframe; observations are registered for its points that exist in the map.
  Keyframe& AddKeyframe(Keyframe keyframe);
  Keyframe* FindKeyframe(KeyframeId id);
  const Keyframe* FindKeyframe(KeyframeId id) const;
  // Removes a keyframe, its observations, and points left with fewer than 2 observations;
  // reconnects its children in the spanning tree.
  void RemoveKeyframe(KeyframeId id);
  const std::unordered_map<KeyframeId, Keyframe>& keyframes() const { return keyframes_; }
  size_t num_keyframes() const { return keyframes_.size(); }

  // --- points
  MapPointId NewPointId();
  MapPoint& AddPoint(MapPoint point);
  MapPoint* FindPoint(MapPointId id);
  const MapPoint* FindPoint(MapPointId id) const;
  // Removes a point and its observations.
  void RemovePoint(MapPointId id);
  const std::unordered_map<MapPointId, MapPoint>& points() const { return points_; }
  size_t num_points() const { return points_.size(); }

  // --- observations
  // Keyframe `kf`'s feature `feature` observes `point` (replacing what the feature observed).
  void AddObservation(KeyframeId kf, int feature, MapPointId point);
  // Keyframe `kf` no longer observes `point`; a point left with fewer than `min_observations`
  // observations is removed.
  void EraseObservation(KeyframeId kf, MapPointId point, int min_observations = 2);
  // Merges `duplicate` into `keep`: every observation of `duplicate` moves to `keep` (unless that
  // keyframe already observes `keep`), then `duplicate` is removed.
  void ReplacePoint(MapPointId duplicate, MapPointId keep);

  // Recomputes a point's representative descriptor (least median distance to its
  // observations), viewing direction and scale-invariance range.
  void UpdatePointAppearance(MapPointId id);
  void UpdatePointGeometry(MapPointId id);

  // --- covisibility
  // Recomputes the keyframe's covisibility from shared points, and its neighbours' too.
  void UpdateConnections(KeyframeId id);
  // Every keyframe's covisibility and spanning-tree parent from scratch, as UpdateConnections on
  // each keyframe in id order would leave them, in one pass (a map read whole: UpdateConnections
  // on each re-sorts every neighbour's list each time).
  void ConnectAll();
  std::vector<KeyframeId> BestCovisible(KeyframeId id, int n) const;
  std::vector<KeyframeId> CovisibleAtLeast(KeyframeId id, int weight) const;

  // Median depth of the keyframe's points in its camera frame (0 if none).
  double MedianDepth(KeyframeId id) const;

  // Ids removed since the last call (for telling copies of this map what disappeared); kept only
  // once the journal is enabled.
  void EnableRemovalJournal() { journal_removals_ = true; }
  std::vector<MapPointId> TakeRemovedPoints();
  std::vector<KeyframeId> TakeRemovedKeyframes();

 private:
  void SetOrderedCovisibility(Keyframe* keyframe);

  SubmapId id_;
  ScalePyramid pyramid_;
  uint32_t next_point_index_;
  std::unordered_map<KeyframeId, Keyframe> keyframes_;
  std::unordered_map<MapPointId, MapPoint> points_;
  bool journal_removals_ = false;
  std::vector<MapPointId> removed_points_;
  std::vector<KeyframeId> removed_keyframes_;
};

// Keyframe from a tracked frame: copies its features and point associations.
Keyframe KeyframeFromFrame(const Frame& frame, KeyframeId id);
// The frame a keyframe was made from, as tracked: its features, pose and point associations (no
// outliers; no sharpness).
Frame FrameFromKeyframe(const Keyframe& keyframe);
// A copy of a keyframe for another map: its features, pose and associations, without what a Map
// maintains (covisibility, spanning tree).
Keyframe UnlinkedCopy(const Keyframe& keyframe);

}  // namespace stitch
