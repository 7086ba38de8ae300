#pragma once
// Descriptor matching between frames, keyframes and map points, guided by geometry (projection
// windows, epipolar lines) or by the vocabulary's direct index, with ORB-SLAM's thresholds: a
// best distance under 50 or 100 bits, a ratio to the second best, and rotation consistency (the
// orientation changes of all matches must agree: only the three most common 12-degree bins are
// kept).

#include <optional>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "stitch/features/descriptor_index.h"
#include "stitch/geometry/camera.h"
#include "stitch/map/map.h"

namespace stitch {

// Initialization: each feature of `reference` up to pyramid level `max_level` (level 0 alone by
// default, as ORB-SLAM) is searched in `current` within `window` px of `previous[i]` (its last
// matched position; initially its own), among the features within `level_slack` levels of its
// own. Returns matches[i] = index in `current` or -1, and updates `previous` for the matched
// features.
int SearchForInitialization(const Frame& reference, const Frame& current, std::vector<Eigen::Vector2d>* previous,
                            std::vector<int>* matches, int window = 100, double ratio = 0.9, int max_level = 0,
                            int level_slack = 0);

// Motion model: the points tracked in `last` are projected into `current` (whose pose must be
// set) and matched within `radius` x scale px, at levels around the one they were seen at.
// Assigns current->points; returns the number of new matches.
int SearchByProjection(Frame* current, const Frame& last, const Map& map, const PinholeIntrinsics& k, double radius);

// The same with the positions predicted by other means (a homography): predicted[i] is where
// feature i of `last` should appear in `current` (undistorted pixels), or none.
int SearchAroundPredictions(Frame* current, const Frame& last, const Map& map,
                            const std::vector<std::optional<Eigen::Vector2d>>& predicted, double radius);

// Without a pose: each usable feature (keypoints/descriptors of a keyframe or frame) is looked
// up in `index` (built on frame.descriptors) among the frame's features that have no point yet;
// best under 50 bits, `ratio` to the second best, each frame feature to its closest, rotation-
// consistent. Returns (feature, frame feature) pairs.
std::vector<std::pair<int, int>> MatchByIndex(const std::vector<cv::KeyPoint>& keypoints, const cv::Mat& descriptors,
                                              const std::vector<char>& usable, const Frame& frame,
                                              const DescriptorIndex& index, double ratio = 0.8);

// Reference keyframe without the vocabulary: the keyframe's points matched to the frame through
// an index over the frame's descriptors (brute force or LSH). Assigns frame->points.
int SearchByIndex(const Keyframe& keyframe, Frame* frame, const Map& map, const DescriptorIndex& index,
                  double ratio = 0.7);

// A local map point predicted in a frame.
struct PointInView {
  MapPointId id;
  Eigen::Vector2d pixel;
  int predicted_level = 0;
  double view_cosine = 1;  // cosine between the viewing ray and the point's mean direction
};

// Whether `point` is in view of a camera at `cam_from_world`: in front, inside the image bounds,
// within its scale-invariance range, seen from within 60 degrees of its mean direction.
bool PredictInView(const MapPoint& point, const Rigid3d& cam_from_world, const PinholeIntrinsics& k, double min_x,
                   double min_y, double max_x, double max_y, const ScalePyramid& pyramid, PointInView* view);

// Local map: points predicted in view (and not yet matched) are matched within a window that
// grows with the predicted level and with oblique views.
int SearchByProjection(Frame* frame, const std::vector<PointInView>& points, const Map& map, double threshold,
                       double ratio = 0.8);

// Reference keyframe: the keyframe's points matched to the frame's features under the same
// vocabulary node (both must have their bag of words computed). Assigns frame->points.
int SearchByBow(const Keyframe& keyframe, Frame* frame, const Map& map, double ratio = 0.7);

// Place recognition: features of `a` and `b` that both observe a map point (of their own
// submaps), matched under the same vocabulary node. Returns (feature in a, feature in b) pairs.
std::vector<std::pair<int, int>> MatchKeyframesByBow(const Keyframe& a, const Map& map_a, const Keyframe& b,
                                                     const Map& map_b, double ratio = 0.75);

// Triangulation: unmatched features of kf1 and kf2 under the same vocabulary node whose positions
// agree with the epipolar geometry (`f21`: x2^T f21 x1 = 0 in undistorted pixels) and are not
// near the epipole. Returns (feature in kf1, feature in kf2) pairs.
std::vector<std::pair<int, int>> SearchForTriangulation(const Keyframe& kf1, const Keyframe& kf2,
                                                        const Eigen::Matrix3d& f21, const PinholeIntrinsics& k,
                                                        const ScalePyramid& pyramid);

// Fundamental matrix mapping undistorted pixels of kf1 to epipolar lines in kf2.
Eigen::Matrix3d FundamentalMatrix(const Rigid3d& cam1_from_world, const Rigid3d& cam2_from_world,
                                  const PinholeIntrinsics& k);

// Which features around a candidate's projection `Fuse` compares it with.
enum class FuseSearch {
  // Those within the 95% bound of their level's noise too (chi2 5.99): the keyframe and the
  // candidates were placed together (a mapper's own keyframes).
  kWithinNoise,
  // The whole radius: the candidates come from another submap, whose placement can be a few
  // pixels off until the adjustment that the fused points then make possible.
  kWholeRadius,
};

// Projects `candidates` into `keyframe` and, for each that lands on a matching feature within
// `radius` pixels (times the level's scale), either adds the observation (feature unmatched) or
// merges the two points (feature already has one; the one with more observations is kept).
// Returns the number of points fused or added.
int Fuse(Map* map, KeyframeId keyframe, const std::vector<MapPointId>& candidates, const PinholeIntrinsics& k,
         double radius = 3.0, FuseSearch search = FuseSearch::kWithinNoise);

}  // namespace stitch
