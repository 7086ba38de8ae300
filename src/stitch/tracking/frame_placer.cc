#include "stitch/tracking/frame_placer.h"

#include <algorithm>
#include <cstdlib>
#include <map>
#include <set>

#include <opencv2/calib3d.hpp>

#include "stitch/estimators/pnp.h"
#include "stitch/estimators/pose_optimizer.h"
#include "stitch/map/matcher.h"
#include "stitch/util/time.h"

namespace stitch {
namespace {

constexpr int kMaxLocalKeyframes = 80;
// A motion model keeping under this fraction of the last frame's points is checked against the
// homography (when homography tracking is on).
constexpr double kWeakMotionModel = 0.2;

// Region of interest: of the features marked in `use`, those in the feature-rich cells of an
// 8x6 grid over the image (at least half the mean count of the occupied cells), at most
// `per_cell` of the strongest in each. Cells with a few features carry the least texture and
// the most ambiguous matches; the cap keeps the homography's support spread over the image.
std::vector<char> FeatureRichCells(const Frame& frame, const std::vector<char>& use, int per_cell) {
  constexpr int kCellsX = 8, kCellsY = 6;
  double min_x = 1e18, min_y = 1e18, max_x = -1e18, max_y = -1e18;
  for (const auto& p : frame.undistorted) {
    min_x = std::min(min_x, p.x());
    min_y = std::min(min_y, p.y());
    max_x = std::max(max_x, p.x());
    max_y = std::max(max_y, p.y());
  }
  std::vector<std::vector<int>> cells(kCellsX * kCellsY);
  for (size_t i = 0; i < frame.size(); ++i) {
    if (!use[i]) continue;
    const int cx = std::clamp(static_cast<int>(kCellsX * (frame.undistorted[i].x() - min_x) / (max_x - min_x + 1e-9)),
                              0, kCellsX - 1);
    const int cy = std::clamp(static_cast<int>(kCellsY * (frame.undistorted[i].y() - min_y) / (max_y - min_y + 1e-9)),
                              0, kCellsY - 1);
    cells[cy * kCellsX + cx].push_back(static_cast<int>(i));
  }
  int occupied = 0, total = 0;
  for (const auto& cell : cells) {
    occupied += !cell.empty();
    total += static_cast<int>(cell.size());
  }
  std::vector<char> chosen(frame.size(), 0);
  if (occupied == 0) return chosen;
  const double rich = 0.5 * total / occupied;
  for (auto& cell : cells) {
    if (cell.empty() || cell.size() < rich) continue;
    std::sort(cell.begin(), cell.end(),
              [&](int a, int b) { return frame.keypoints[a].response > frame.keypoints[b].response; });
    for (size_t k = 0; k < cell.size() && static_cast<int>(k) < per_cell; ++k) chosen[cell[k]] = 1;
  }
  return chosen;
}

}  // namespace

FramePlacer::FramePlacer(const TrackingOptions& options, const ViewGeometry* geometry, const Vocabulary* vocabulary,
                         std::function<void()> wait_for_keyframe_bow)
    : options_(options),
      geometry_(geometry),
      vocabulary_(vocabulary),
      wait_for_keyframe_bow_(std::move(wait_for_keyframe_bow)) {}

FramePlacer::Placement FramePlacer::Place(Frame* frame, const Map& map, const Frame* last,
                                          const std::optional<Rigid3d>& velocity, int min_inliers,
                                          KeyframeId* reference) {
  // With homography tracking, a placement the local map does not confirm gives way to the next
  // method (a wrong constant-velocity guess under jitter can still find 20 chance matches).
  Placement result;
  pose_diverged_ = false;
  const Stopwatch clock;
  const bool retry = options_.homography_tracking;
  const auto attempt = [&](const char* method, const std::function<bool()>& place) {
    if (result.tracked || (result.placed && !retry)) return;
    const double t0 = clock.ElapsedMs();
    result.placed = place();
    const double t1 = clock.ElapsedMs();
    result.frame_to_frame_ms += t1 - t0;
    if (!result.placed) return;
    result.tracked = TrackLocalMap(map, frame, min_inliers, reference);
    result.local_map_ms += clock.ElapsedMs() - t1;
    if (result.tracked) result.tracked_by = method;
  };
  // `last` may be a later frame (frames placed backward): the velocity then runs backward too.
  const int gap = last ? std::abs(frame->frame_index - last->frame_index) : 0;
  int motion_inliers = 0;
  if (velocity && last && gap >= 1) {
    Rigid3d predicted = *last->cam_from_world;
    for (int i = 0; i < gap; ++i) predicted = *velocity * predicted;
    attempt("motion model", [&] { return (motion_inliers = TrackWithMotionModel(map, frame, *last, predicted)) > 0; });
  }
  if (result.tracked && retry && motion_inliers < kWeakMotionModel * last->CountTracked()) {
    // The motion model kept few of the last frame's points: a wrong guess that chance matches
    // confirmed, or a right one under a shaking camera. The homography decides: the placement
    // the local map supports better stays.
    const Frame motion_placed = *frame;
    const KeyframeId motion_reference = *reference;
    const int motion_tracked = frame->CountTracked();
    result.tracked = false;
    attempt("homography", [&] { return TrackWithHomography(map, frame, *last); });
    if (!result.tracked || frame->CountTracked() <= motion_tracked) {
      *frame = motion_placed;
      *reference = motion_reference;
      result.tracked = true;
      result.tracked_by = "motion model";
    }
  }
  if (options_.homography_tracking && last)
    attempt("homography", [&] { return TrackWithHomography(map, frame, *last); });
  attempt("reference keyframe", [&] { return TrackReferenceKeyframe(map, frame, last, reference); });
  result.pose_diverged = pose_diverged_;
  return result;
}

int FramePlacer::OptimizeFramePose(const Map& map, Frame* frame, bool discard_outliers) {
  std::vector<PoseObservation> observations;
  std::vector<int> features;
  for (size_t i = 0; i < frame->size(); ++i) {
    if (!frame->points[i].valid()) continue;
    const MapPoint* point = map.FindPoint(frame->points[i]);
    if (!point) {
      frame->points[i] = MapPointId();
      continue;
    }
    observations.push_back(
        {frame->undistorted[i], point->position, geometry_->pyramid.inverse_sigma2[frame->keypoints[i].octave]});
    features.push_back(static_cast<int>(i));
  }
  if (observations.size() < 3) return 0;
  const PoseOptimizerResult optimized = OptimizePose(observations, *frame->cam_from_world, geometry_->intrinsics);
  if (!optimized.converged) {
    pose_diverged_ = true;
    return 0;
  }
  frame->cam_from_world = optimized.cam_from_world;
  int inliers = 0;
  for (size_t o = 0; o < features.size(); ++o) {
    const int i = features[o];
    frame->outlier[i] = !optimized.inlier[o];
    if (frame->outlier[i] && discard_outliers) {
      frame->points[i] = MapPointId();
      frame->outlier[i] = 0;
    }
    inliers += optimized.inlier[o];
  }
  return inliers;
}

int FramePlacer::TrackWithMotionModel(const Map& map, Frame* frame, const Frame& last, const Rigid3d& predicted) {
  frame->cam_from_world = predicted;
  std::fill(frame->points.begin(), frame->points.end(), MapPointId());
  int matches = SearchByProjection(frame, last, map, geometry_->intrinsics, 15.0);
  if (matches < 20) {
    std::fill(frame->points.begin(), frame->points.end(), MapPointId());
    matches = SearchByProjection(frame, last, map, geometry_->intrinsics, 30.0);
  }
  if (matches < 20) return 0;
  const int inliers = OptimizeFramePose(map, frame, true);
  return inliers >= 10 ? inliers : 0;
}

const DescriptorIndex& FramePlacer::FrameIndex(const Frame& frame) {
  if (!frame_index_ || frame_index_of_ != frame.frame_index || frame_index_->size() != static_cast<int>(frame.size())) {
    // LSH for the homography's matching when the reference keyframe goes by bag of words.
    const DescriptorSearch search = options_.reference_matching == "bow"
                                        ? DescriptorSearch::kLsh
                                        : ParseDescriptorSearch(options_.reference_matching);
    frame_index_.emplace(frame.descriptors, search);
    frame_index_of_ = frame.frame_index;
  }
  return *frame_index_;
}

bool FramePlacer::PoseFromMatches(const Map& map, Frame* frame) {
  std::vector<PnpMatch> matches;
  std::vector<int> features;
  for (size_t i = 0; i < frame->size(); ++i) {
    const MapPoint* point = frame->points[i].valid() ? map.FindPoint(frame->points[i]) : nullptr;
    if (!point) continue;
    matches.push_back({frame->undistorted[i], point->position, geometry_->pyramid.scale[frame->keypoints[i].octave]});
    features.push_back(static_cast<int>(i));
  }
  const std::optional<PnpResult> pnp = EstimatePoseRansac(matches, geometry_->intrinsics);
  if (!pnp) return false;
  for (size_t m = 0; m < features.size(); ++m) {
    if (!pnp->inlier[m]) frame->points[features[m]] = MapPointId();
  }
  frame->cam_from_world = pnp->cam_from_world;
  return OptimizeFramePose(map, frame, true) >= 10;
}

bool FramePlacer::TrackWithHomography(const Map& map, Frame* frame, const Frame& last) {
  // A frame followed by optical flow has no descriptors to match.
  if (last.descriptors.rows != static_cast<int>(last.size())) return false;
  // Where the last frame's tracked features went, from descriptors alone (no pose needed).
  std::fill(frame->points.begin(), frame->points.end(), MapPointId());
  std::vector<char> tracked(last.size(), 0);
  for (size_t i = 0; i < last.size(); ++i) tracked[i] = last.points[i].valid() && !last.outlier[i];
  const std::vector<char> queried = options_.homography_roi_per_cell > 0
                                        ? FeatureRichCells(last, tracked, options_.homography_roi_per_cell)
                                        : tracked;
  const auto matches = MatchByIndex(last.keypoints, last.descriptors, queried, *frame, FrameIndex(*frame), 0.8);
  if (matches.size() < 15) return false;
  std::vector<cv::Point2f> from, to;
  for (const auto& [i, j] : matches) {
    from.emplace_back(static_cast<float>(last.undistorted[i].x()), static_cast<float>(last.undistorted[i].y()));
    to.emplace_back(static_cast<float>(frame->undistorted[j].x()), static_cast<float>(frame->undistorted[j].y()));
  }
  std::vector<uchar> inlier;
  const cv::Mat h = cv::findHomography(from, to, cv::RANSAC, options_.homography_threshold_px, inlier, 500, 0.995);
  if (h.empty() || std::count(inlier.begin(), inlier.end(), 1) < 12) return false;
  // Every tracked feature searched around where the homography puts it.
  Eigen::Matrix3d hm;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) hm(r, c) = h.at<double>(r, c);
  }
  std::vector<std::optional<Eigen::Vector2d>> predicted(last.size());
  for (size_t i = 0; i < last.size(); ++i) {
    if (!tracked[i]) continue;
    const Eigen::Vector3d p = hm * last.undistorted[i].homogeneous();
    if (p.z() > 1e-9) predicted[i] = p.hnormalized();
  }
  if (SearchAroundPredictions(frame, last, map, predicted, options_.homography_search_px) < 20) return false;
  return PoseFromMatches(map, frame);
}

bool FramePlacer::TrackReferenceKeyframe(const Map& map, Frame* frame, const Frame* last, KeyframeId* reference_id) {
  const Keyframe* reference = map.FindKeyframe(*reference_id);
  if (!reference) {
    // The reference was culled: the newest keyframe serves.
    KeyframeId newest;
    for (const auto& [id, kf] : map.keyframes()) newest = std::max(newest, id);
    *reference_id = newest;
    reference = map.FindKeyframe(newest);
    if (!reference) return false;
  }
  std::fill(frame->points.begin(), frame->points.end(), MapPointId());
  int matches = 0;
  if (options_.reference_matching == "bow") {
    // Its bag of words may still be on the worker (adopting it adds or removes no keyframe).
    if (reference->bow.empty() && wait_for_keyframe_bow_) wait_for_keyframe_bow_();
    ComputeBow(*vocabulary_, frame);
    matches = SearchByBow(*reference, frame, map);
  } else {
    matches = SearchByIndex(*reference, frame, map, FrameIndex(*frame));
  }
  if (matches < 15) return false;
  frame->cam_from_world = last ? *last->cam_from_world : reference->cam_from_world;
  return OptimizeFramePose(map, frame, true) >= 10;
}

bool FramePlacer::TrackLocalMap(const Map& map, Frame* frame, int min_inliers, KeyframeId* reference) {
  // Local keyframes: those observing the frame's points, their best neighbours, children, parent.
  std::map<KeyframeId, int> counts;
  for (size_t i = 0; i < frame->size(); ++i) {
    if (!frame->points[i].valid() || frame->outlier[i]) continue;
    if (const MapPoint* point = map.FindPoint(frame->points[i])) {
      for (const auto& [kf, feature] : point->observations) ++counts[kf];
    }
  }
  std::vector<std::pair<int, KeyframeId>> ranked;
  for (const auto& [kf, count] : counts) ranked.push_back({count, kf});
  std::sort(ranked.begin(), ranked.end(), [](const auto& a, const auto& b) {
    return a.first > b.first || (a.first == b.first && a.second < b.second);
  });
  std::set<KeyframeId> local;
  local_keyframes_.clear();
  const auto add = [&](KeyframeId id) {
    if (id.valid() && map.FindKeyframe(id) && local.insert(id).second) local_keyframes_.push_back(id);
  };
  for (const auto& [count, kf] : ranked) {
    if (static_cast<int>(local_keyframes_.size()) >= kMaxLocalKeyframes) break;
    add(kf);
  }
  const size_t direct = local_keyframes_.size();
  for (size_t i = 0; i < direct && static_cast<int>(local_keyframes_.size()) < kMaxLocalKeyframes; ++i) {
    const Keyframe* kf = map.FindKeyframe(local_keyframes_[i]);
    for (KeyframeId neighbour : map.BestCovisible(kf->id, 10)) add(neighbour);
    for (KeyframeId child : kf->children) add(child);
    add(kf->parent);
  }
  if (!ranked.empty()) *reference = ranked.front().second;

  // Local points not yet matched, predicted in view, searched by projection.
  // Every id once, in the local keyframes' order (a std::set here took a third of the time).
  seen_points_.Clear(4 * frame->size());
  for (size_t i = 0; i < frame->size(); ++i) {
    if (frame->points[i].valid()) seen_points_.Insert(frame->points[i].value);
  }
  std::vector<MapPointId> candidates;
  for (KeyframeId id : local_keyframes_) {
    for (MapPointId p : map.FindKeyframe(id)->points) {
      if (p.valid() && seen_points_.Insert(p.value)) candidates.push_back(p);
    }
  }
  std::vector<PointInView> in_view;
  for (MapPointId p : candidates) {
    const MapPoint* point = map.FindPoint(p);
    PointInView view;
    if (point && geometry_->InView(*point, *frame->cam_from_world, &view)) in_view.push_back(view);
  }
  SearchByProjection(frame, in_view, map, 1.0);
  return OptimizeFramePose(map, frame, false) >= min_inliers;
}

}  // namespace stitch
