#include "stitch/tracking/initializer.h"

#include <algorithm>
#include <cstdio>

#include "stitch/estimators/bundle_adjustment.h"
#include "stitch/estimators/pose_optimizer.h"
#include "stitch/estimators/two_view.h"
#include "stitch/map/matcher.h"

namespace stitch {
namespace {
constexpr double kChi2TwoDof = 5.991;  // 95%, two degrees of freedom (a reprojection error)
// A point is culled when at least this many of the frames it waited through, and this fraction
// of those that saw it, see it farther from where it projects than kChi2TwoDof allows.
constexpr int kMinDisagreeing = 2;
constexpr double kDisagreeingFraction = 0.3;
}  // namespace

Initializer::Initializer(const TrackingOptions& options, const ViewGeometry* geometry, const Vocabulary* vocabulary)
    : options_(options), geometry_(geometry), vocabulary_(vocabulary) {}

void Initializer::Reset() {
  reference_.reset();
  across_levels_ = false;
  previous_.clear();
  between_.clear();
  refused_ = 0;
  last_refusal_.clear();
}

Initializer::Result Initializer::Add(Frame frame, SubmapId submap) {
  Result result;
  if (static_cast<int>(frame.size()) <= options_.init_min_features) {
    Reset();
    result.reason = TrackingReason::kTooFewFeatures;
    result.detail =
        std::to_string(frame.size()) + " features, initialization needs " + std::to_string(options_.init_min_features);
    return result;
  }
  if (!reference_) {
    previous_ = frame.undistorted;
    reference_ = std::move(frame);
    result.detail = "reference frame set, waiting for parallax";
    return result;
  }
  std::vector<int> matches;
  const int count = MatchReference(frame, &matches);
  if (count < options_.init_min_matches) {
    result.reason = TrackingReason::kTooFewMatches;
    result.detail = std::to_string(count) + " matches with the reference frame; it is replaced by this frame";
    previous_ = frame.undistorted;
    reference_ = std::move(frame);
    across_levels_ = false;
    between_.clear();
    refused_ = 0;
    last_refusal_.clear();
    return result;
  }
  std::vector<Eigen::Vector2d> p1, p2;
  std::vector<int> index_of;
  for (size_t i = 0; i < matches.size(); ++i) {
    if (matches[i] < 0) continue;
    p1.push_back(reference_->undistorted[i]);
    p2.push_back(frame.undistorted[matches[i]]);
    index_of.push_back(static_cast<int>(i));
  }
  std::string why;
  const auto two_view = InitializeTwoView(p1, p2, geometry_->intrinsics, options_.initialization, &why, across_levels_);
  if (!two_view) {
    result.detail = why;
    ++refused_;
    last_refusal_ = why;
    if (options_.place_initialization_frames) {
      if (between_.size() == kMaxBetween) between_.erase(between_.begin());
      Between b;
      b.frame_index = frame.frame_index;
      b.t_ns = frame.t_ns;
      b.num_features = static_cast<int>(frame.size());
      for (size_t i = 0; i < matches.size(); ++i) {
        if (matches[i] < 0) continue;
        b.reference_features.push_back(static_cast<int>(i));
        b.pixels.push_back(frame.undistorted[matches[i]]);
        b.inverse_sigma2.push_back(geometry_->pyramid.inverse_sigma2[frame.keypoints[matches[i]].octave]);
      }
      between_.push_back(std::move(b));
    }
    return result;
  }
  // Expand the per-match result back to reference feature indices.
  TwoViewResult expanded = *two_view;
  expanded.points_in_cam1.assign(reference_->size(), Eigen::Vector3d::Zero());
  expanded.triangulated.assign(reference_->size(), 0);
  for (size_t m = 0; m < index_of.size(); ++m) {
    expanded.points_in_cam1[index_of[m]] = two_view->points_in_cam1[m];
    expanded.triangulated[index_of[m]] = two_view->triangulated[m];
  }
  result.map = BuildMap(&frame, matches, expanded, submap, &why);
  if (result.map && options_.place_initialization_frames) {
    result.earlier = PlaceEarlierFrames(*result.map, *reference_, frame);
  }
  if (!result.map) {
    Reset();
    result.detail = why;
    return result;
  }
  result.reason = TrackingReason::kNone;
  result.detail = DescribeInitialization(*two_view, frame.frame_index - reference_->frame_index);
  Reset();
  result.frame = std::move(frame);
  return result;
}

int Initializer::MatchReference(const Frame& frame, std::vector<int>* matches) {
  if (across_levels_) {
    return SearchForInitialization(*reference_, frame, &previous_, matches, options_.init_window_px, kMatchRatio,
                                   kMaxLevel, 1);
  }
  if (!options_.init_across_levels) {
    return SearchForInitialization(*reference_, frame, &previous_, matches, options_.init_window_px);
  }
  std::vector<Eigen::Vector2d> previous = previous_;
  const int count = SearchForInitialization(*reference_, frame, &previous, matches, options_.init_window_px);
  if (count >= options_.init_min_matches) {
    previous_ = std::move(previous);
    return count;
  }
  // Too few level-0 matches: a camera that turned away, or one that moved toward the scene, whose
  // features grew out of level 0. Across levels, the second shows as most matches a level larger.
  std::vector<Eigen::Vector2d> previous_across = previous_;
  std::vector<int> matches_across;
  const int count_across = SearchForInitialization(*reference_, frame, &previous_across, &matches_across,
                                                   options_.init_window_px, kMatchRatio, kMaxLevel, 1);
  int grown = 0;
  for (size_t i = 0; i < matches_across.size(); ++i) {
    if (matches_across[i] >= 0) grown += frame.keypoints[matches_across[i]].octave > reference_->keypoints[i].octave;
  }
  if (count_across < options_.init_min_matches || grown < kGrownFraction * count_across) {
    previous_ = std::move(previous);
    return count;
  }
  across_levels_ = true;
  previous_ = std::move(previous_across);
  *matches = std::move(matches_across);
  return count_across;
}

std::string Initializer::DescribeInitialization(const TwoViewResult& two_view, int frames_since_reference) const {
  char rule[80];
  if (across_levels_) {
    std::snprintf(rule, sizeof(rule), "the essential matrix alone, the camera moving toward the scene");
  } else {
    std::snprintf(rule, sizeof(rule), "choosing it above %.2f", options_.initialization.homography_ratio);
  }
  char figures[240];
  std::snprintf(figures, sizeof(figures),
                " (homography's share of the score %.2f, %s) with %d points, parallax %.1f deg, %d frames after its "
                "reference",
                two_view.homography_share, rule, two_view.num_triangulated, two_view.parallax_deg,
                frames_since_reference);
  std::string detail =
      std::string("initialized from ") + (two_view.used_homography ? "a homography" : "an essential matrix") + figures;
  if (across_levels_) detail += ", matched across pyramid levels";
  if (culled_ > 0) {
    detail += "; " + std::to_string(culled_) + " points the frames it waited through saw elsewhere were dropped";
  }
  if (refused_ > 0) {
    detail += "; " + std::to_string(refused_) + (refused_ == 1 ? " attempt" : " attempts") +
              " refused before it, the last: " + last_refusal_;
  }
  return detail;
}

std::unique_ptr<Map> Initializer::BuildMap(Frame* frame, const std::vector<int>& matches, const TwoViewResult& two_view,
                                           SubmapId submap, std::string* why) {
  auto map = std::make_unique<Map>(submap, geometry_->pyramid, 0);
  Frame& reference = *reference_;
  ComputeBow(*vocabulary_, &reference);
  ComputeBow(*vocabulary_, frame);
  reference.cam_from_world = Rigid3d();
  frame->cam_from_world = two_view.cam2_from_cam1;
  reference.points.assign(reference.size(), MapPointId());
  frame->points.assign(frame->size(), MapPointId());
  for (size_t i = 0; i < matches.size(); ++i) {
    if (matches[i] < 0 || !two_view.triangulated[i]) continue;
    MapPoint point;
    point.id = map->NewPointId();
    point.position = two_view.points_in_cam1[i];
    reference.points[i] = point.id;
    frame->points[matches[i]] = point.id;
    map->AddPoint(point);
  }
  const KeyframeId id0 = MakeKeyframeId(submap, 0), id1 = MakeKeyframeId(submap, 1);
  map->AddKeyframe(KeyframeFromFrame(reference, id0));
  map->AddKeyframe(KeyframeFromFrame(*frame, id1));
  for (const auto& [id, point] : map->points()) {
    map->UpdatePointAppearance(id);
    map->UpdatePointGeometry(id);
  }
  map->UpdateConnections(id0);
  map->UpdateConnections(id1);
  BundleAdjustmentOptions ba;
  ba.iterations = 20;
  ba.refine_iterations = 0;
  BundleAdjust(map.get(), {id1}, {id0}, geometry_->intrinsics, ba);
  // The frames it waited through see each point too: one they see elsewhere than it projects was
  // matched to a look-alike along its epipolar line (a facade's repeated windows ahead of a car),
  // which two views cannot tell, and its depth would set a wrong scale for the frames to come.
  culled_ = 0;
  if (options_.place_initialization_frames && !between_.empty()) {
    culled_ = CullPointsTheEarlierFramesDisagreeWith(map.get(), PlaceEarlierFrames(*map, reference, *frame));
    if (culled_ > 0) BundleAdjust(map.get(), {id1}, {id0}, geometry_->intrinsics, ba);
  }
  const double median_depth = map->MedianDepth(id0);
  const int tracked = map->FindKeyframe(id1)->CountPoints();
  if (median_depth <= 0 || tracked < options_.init_min_matches) {
    *why = "initial map rejected: median depth " + std::to_string(median_depth) + ", " + std::to_string(tracked) +
           " points";
    return nullptr;
  }
  // Unit median depth: the submap's scale (monocular scale is arbitrary).
  const double scale = 1.0 / median_depth;
  Keyframe* kf1 = map->FindKeyframe(id1);
  kf1->cam_from_world.translation *= scale;
  std::vector<MapPointId> ids;
  for (const auto& [id, point] : map->points()) ids.push_back(id);
  for (MapPointId id : ids) {
    map->FindPoint(id)->position *= scale;
    map->UpdatePointGeometry(id);
  }
  frame->cam_from_world = kf1->cam_from_world;
  frame->points = kf1->points;
  frame->outlier.assign(frame->size(), 0);
  return map;
}

int Initializer::CullPointsTheEarlierFramesDisagreeWith(Map* map,
                                                        const std::vector<Result::PlacedFrame>& placed) const {
  const Keyframe* kf0 = map->FindKeyframe(MakeKeyframeId(map->id(), 0));
  if (!kf0) return 0;
  std::vector<int> seen(kf0->points.size(), 0), disagree(kf0->points.size(), 0);
  for (const Result::PlacedFrame& p : placed) {
    if (p.is_reference) continue;
    const auto b = std::find_if(between_.begin(), between_.end(),
                                [&](const Between& x) { return x.frame_index == p.frame_index; });
    if (b == between_.end()) continue;
    for (size_t m = 0; m < b->reference_features.size(); ++m) {
      const size_t i = static_cast<size_t>(b->reference_features[m]);
      if (i >= kf0->points.size() || !kf0->points[i].valid()) continue;
      const MapPoint* point = map->FindPoint(kf0->points[i]);
      if (!point) continue;
      ++seen[i];
      const Eigen::Vector3d in_cam = p.cam_from_world * point->position;
      const double e2 =
          in_cam.z() > 0 ? (geometry_->intrinsics.Project(in_cam) - b->pixels[m]).squaredNorm() * b->inverse_sigma2[m]
                         : 1e18;
      disagree[i] += e2 > kChi2TwoDof;
    }
  }
  std::vector<MapPointId> culled;
  for (size_t i = 0; i < seen.size(); ++i) {
    if (disagree[i] >= kMinDisagreeing && disagree[i] >= kDisagreeingFraction * seen[i])
      culled.push_back(kf0->points[i]);
  }
  for (MapPointId id : culled) map->RemovePoint(id);
  return static_cast<int>(culled.size());
}

std::vector<Initializer::Result::PlacedFrame> Initializer::PlaceEarlierFrames(const Map& map, const Frame& reference,
                                                                              const Frame& frame) const {
  std::vector<Result::PlacedFrame> placed;
  const Keyframe* kf0 = map.FindKeyframe(MakeKeyframeId(map.id(), 0));
  const Keyframe* kf1 = map.FindKeyframe(MakeKeyframeId(map.id(), 1));
  if (!kf0 || !kf1) return placed;
  placed.push_back({reference.frame_index, reference.t_ns, kf0->cam_from_world, static_cast<int>(reference.size()),
                    kf0->CountPoints(), /*is_reference=*/true});
  const int span = frame.frame_index - reference.frame_index;
  for (const Between& b : between_) {
    // From the reference's points through the frame's matches with it; the pose starts between
    // the two keyframes' in proportion to the frame's place between them.
    std::vector<PoseObservation> observations;
    for (size_t m = 0; m < b.reference_features.size(); ++m) {
      const size_t i = static_cast<size_t>(b.reference_features[m]);
      const MapPoint* point =
          i < kf0->points.size() && kf0->points[i].valid() ? map.FindPoint(kf0->points[i]) : nullptr;
      if (point) observations.push_back({b.pixels[m], point->position, b.inverse_sigma2[m]});
    }
    if (static_cast<int>(observations.size()) < options_.min_inliers || span <= 0) continue;
    const double t = std::clamp((b.frame_index - reference.frame_index) / static_cast<double>(span), 0.0, 1.0);
    Rigid3d initial;
    initial.rotation = kf0->cam_from_world.rotation.slerp(t, kf1->cam_from_world.rotation);
    initial.translation = (1 - t) * kf0->cam_from_world.translation + t * kf1->cam_from_world.translation;
    const PoseOptimizerResult optimized = OptimizePose(observations, initial, geometry_->intrinsics);
    if (!optimized.converged || optimized.num_inliers < options_.min_inliers) continue;
    placed.push_back({b.frame_index, b.t_ns, optimized.cam_from_world, b.num_features, optimized.num_inliers, false});
  }
  return placed;
}

}  // namespace stitch
