#include "services/tracker/tracking.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <map>
#include <set>

#include <opencv2/calib3d.hpp>

#include "stitch/estimators/pnp.h"
#include "stitch/estimators/pose_optimizer.h"
#include "stitch/map/matcher.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "stitch/util/options.h"
#include "stitch/util/time.h"

namespace stitch {
namespace {

constexpr int kMaxLocalKeyframes = 80;
constexpr int kDirectIndexLevel = 2;
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
    const int cx = std::clamp(static_cast<int>(kCellsX * (frame.undistorted[i].x() - min_x) / (max_x - min_x + 1e-9)), 0, kCellsX - 1);
    const int cy = std::clamp(static_cast<int>(kCellsY * (frame.undistorted[i].y() - min_y) / (max_y - min_y + 1e-9)), 0, kCellsY - 1);
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
    std::sort(cell.begin(), cell.end(), [&](int a, int b) { return frame.keypoints[a].response > frame.keypoints[b].response; });
    for (size_t k = 0; k < cell.size() && static_cast<int>(k) < per_cell; ++k) chosen[cell[k]] = 1;
  }
  return chosen;
}

}  // namespace

bool TrackingOptions::Check(std::string* why) const {
  auto fail = [&](const std::string& m) { if (why) *why = m; return false; };
  if (!orb.Check(why) || !initialization.Check(why)) return false;
  if (init_min_features < 8 || init_min_matches < 8) return fail("tracker: init_min_features and init_min_matches must be >= 8");
  if (init_window_px < 5) return fail("tracker.init_window_px must be >= 5");
  if (min_inliers < 6 || min_inliers_after_failure < min_inliers) {
    return fail("tracker: need 6 <= min_inliers <= min_inliers_after_failure");
  }
  if (lost_after_frames < 1) return fail("tracker.lost_after_frames must be >= 1");
  if (!(keyframe_ratio > 0 && keyframe_ratio < 1)) return fail("tracker.keyframe_ratio must be in (0, 1)");
  if (max_keyframe_gap < 0) return fail("tracker.max_keyframe_gap must be >= 0");
  if (!(min_relative_sharpness >= 0 && min_relative_sharpness < 1)) return fail("tracker.min_relative_sharpness must be in [0, 1)");
  if (relocalize_closed_after_frames < 0) return fail("tracker.relocalize_closed_after_frames must be >= 0");
  if (relocalization_candidates < 1) return fail("tracker.relocalization_candidates must be >= 1");
  if (relocalization_min_inliers < min_inliers) return fail("tracker.relocalization_min_inliers must be >= min_inliers");
  if (reference_matching != "bow" && reference_matching != "lsh" && reference_matching != "brute_force") {
    return fail("tracker.reference_matching must be bow, lsh or brute_force");
  }
  if (!(homography_threshold_px > 0 && homography_threshold_px <= 100)) return fail("tracker.homography_threshold_px must be in (0, 100]");
  if (!(homography_search_px > 0 && homography_search_px <= 200)) return fail("tracker.homography_search_px must be in (0, 200]");
  if (homography_roi_per_cell < 0 || homography_roi_per_cell > 1000) return fail("tracker.homography_roi_per_cell must be in [0, 1000]");
  if (agent_number < 0 || agent_number > 32767) return fail("tracker.agent_number must be in [0, 32767]");
  if (first_submap_number < 1 || first_submap_number > 65535) return fail("tracker.first_submap_number must be in [1, 65535]");
  return true;
}

const char* TrackingStateName(TrackingState state) {
  switch (state) {
    case TrackingState::kInitializing: return "INITIALIZING";
    case TrackingState::kOk: return "OK";
    case TrackingState::kLost: return "LOST";
    case TrackingState::kSkipped: return "SKIPPED";
    case TrackingState::kNotTracked: return "NOT_TRACKED";
  }
  return "?";
}

const char* TrackingReasonName(TrackingReason reason) {
  switch (reason) {
    case TrackingReason::kNone: return "none";
    case TrackingReason::kTooFewFeatures: return "too few features";
    case TrackingReason::kTooFewMatches: return "too few matches";
    case TrackingReason::kInitFailed: return "initialization failed";
    case TrackingReason::kPoseDiverged: return "pose optimization diverged";
    case TrackingReason::kUndecodableFrame: return "undecodable frame";
    case TrackingReason::kDropped: return "dropped";
    case TrackingReason::kNoTracker: return "no tracker";
    case TrackingReason::kMotionBlur: return "motion blur";
    case TrackingReason::kNotRelocalized: return "not relocalized";
  }
  return "?";
}

LossPolicy ParseLossPolicy(const std::string& name) {
  if (name == "submap") return LossPolicy::kNewSubmap;
  if (name == "relocalize") return LossPolicy::kRelocalize;
  throw Error("the loss policy must be submap or relocalize, not '" + name + "'");
}

Tracking::Tracking(const TrackingOptions& options, const Camera& camera, const Vocabulary* vocabulary, double fps,
                   LossPolicy policy)
    : options_(options),
      camera_(camera),
      intrinsics_(camera.Intrinsics()),
      vocabulary_(vocabulary),
      fps_(fps > 0 ? fps : 30.0),
      pyramid_(ScalePyramid::From(options.orb)),
      undistorter_(camera),
      extractor_(options.orb),
      init_extractor_([&] {
        OrbOptions more = options.orb;
        more.num_features *= 2;
        return more;
      }()),
      policy_(policy),
      next_submap_number_(options.first_submap_number) {
  CheckOptions(options_, "tracker");
  if (!vocabulary_ || vocabulary_->empty()) throw Error("Tracking needs a vocabulary");
  if (options_.keyframe_worker) keyframe_worker_ = std::make_unique<WorkerThread>();
}

Tracking::~Tracking() {
  keyframe_worker_.reset();  // finishes its queue while the members its tasks write to still exist
}

void Tracking::AdoptKeyframeBow(bool wait) {
  if (!keyframe_worker_) return;
  if (wait) keyframe_worker_->Drain();
  std::vector<FinishedBow> finished;
  {
    std::lock_guard<std::mutex> lock(finished_mutex_);
    finished.swap(finished_bow_);
  }
  for (FinishedBow& f : finished) {
    Keyframe* keyframe = map_ ? map_->FindKeyframe(f.keyframe) : nullptr;
    for (auto& closed : closed_maps_) {
      if (!keyframe) keyframe = closed.map->FindKeyframe(f.keyframe);
    }
    if (!keyframe) continue;  // culled by the mapper meanwhile
    keyframe->bow = std::move(f.bow);
    keyframe->bow_features = std::move(f.features);
    AddToDatabase(*keyframe);
  }
}

void Tracking::ComputeBow(Frame* frame) const {
  if (frame->bow.empty()) frame->bow = vocabulary_->Transform(frame->descriptors, &frame->bow_features, kDirectIndexLevel);
}

void Tracking::ResetInitialization() {
  init_reference_.reset();
  init_previous_.clear();
}

std::optional<SubmapId> Tracking::CloseSubmap() {
  if (!map_) return std::nullopt;
  const SubmapId id = map_->id();
  ShelveCurrentSubmap();
  ++submaps_closed_;
  last_frame_.reset();
  velocity_.reset();
  reference_keyframe_ = KeyframeId();
  local_keyframes_.clear();
  consecutive_failures_ = 0;
  typical_sharpness_ = 0;
  lost_ = false;
  frames_initializing_ = 0;
  ResetInitialization();
  return id;
}

void Tracking::ShelveCurrentSubmap() {
  if (!map_) return;
  closed_maps_.push_back({std::move(map_), next_keyframe_index_});
}

void Tracking::ReopenSubmap(SubmapId id) {
  for (auto it = closed_maps_.begin(); it != closed_maps_.end(); ++it) {
    if (it->map->id() != id) continue;
    map_ = std::move(it->map);
    next_keyframe_index_ = it->next_keyframe_index;
    closed_maps_.erase(it);
    return;
  }
}

void Tracking::AddToDatabase(const Keyframe& keyframe) {
  database_.Add(keyframe.id.value, SubmapOf(keyframe.id).value, keyframe.bow);
}

Tracking::Output Tracking::Track(const cv::Mat& image, int frame_index, int64_t t_ns) {
  const Stopwatch total;
  AdoptKeyframeBow(/*wait=*/false);
  Output output = TrackFrame(image, frame_index, t_ns);
  TrackResult& result = output.result;
  result.timings.total = total.ElapsedMs();
  // Every change of state is logged with its frame and reason.
  if (result.state != last_state_ || result.relocalized || output.closed_submap) {
    std::string text = "frame " + std::to_string(frame_index) + ": " + TrackingStateName(last_state_) + " -> " +
                       TrackingStateName(result.state);
    if (result.state == TrackingState::kOk) {
      text += " in submap " + SubmapName(result.submap);
    } else if (result.reason != TrackingReason::kNone) {
      text += std::string(" (") + TrackingReasonName(result.reason) + ")";
    }
    if (!result.detail.empty()) text += ": " + result.detail;
    STITCH_LOG(INFO) << text;
    last_state_ = result.state;
  }
  return output;
}

Tracking::Output Tracking::TrackFrame(const cv::Mat& image, int frame_index, int64_t t_ns) {
  pose_diverged_ = false;
  if (!map_) {
    Frame frame = MakeFrame(image, frame_index, t_ns, &init_extractor_, undistorter_);
    // The method re-initializes at once. When the new map cannot initialize (no parallax: hover,
    // pure rotation), the camera may be back over a closed submap and relocalize there.
    ++frames_initializing_;
    const bool may_relocalize = !closed_maps_.empty() && frames_initializing_ > options_.relocalize_closed_after_frames &&
                                static_cast<int>(frame.size()) > options_.init_min_features;
    std::optional<Frame> copy;
    if (may_relocalize) copy = frame;
    Output output = Initialize(std::move(frame));
    if (may_relocalize && output.result.state != TrackingState::kOk) {
      Output relocalized;
      if (Relocalize(&*copy, &relocalized)) return relocalized;
    }
    return output;
  }
  Stopwatch step;
  Frame frame = MakeFrame(image, frame_index, t_ns, &extractor_, undistorter_);
  Output output;
  TrackResult& result = output.result;
  result.timings.extraction = step.ElapsedMs();
  result.submap = map_->id();
  result.num_features = static_cast<int>(frame.size());
  if (lost_) {
    // Relocalize policy: every frame is tried against the kept map, or discarded.
    if (frame.size() >= 20 && Relocalize(&frame, &output)) return output;
    result.state = TrackingState::kLost;
    result.reason = TrackingReason::kNotRelocalized;
    result.detail = "not relocalized in submap " + SubmapName(map_->id()) + "; frame discarded";
    result.submap_keyframes = static_cast<int>(map_->num_keyframes());
    return output;
  }
  bool ok = false;
  std::string why;
  const bool blurred = typical_sharpness_ > 0 && frame.sharpness < options_.min_relative_sharpness * typical_sharpness_;
  if (frame.size() < 20) {
    why = std::to_string(frame.size()) + " features";
    result.reason = TrackingReason::kTooFewFeatures;
  } else if (blurred) {
    // A gust smears the image: matches on a blurred frame give wrong poses that look right.
    char text[96];
    std::snprintf(text, sizeof(text), "motion blur (sharpness %.1f, recent frames %.1f)", frame.sharpness, typical_sharpness_);
    why = text;
    result.reason = TrackingReason::kMotionBlur;
  } else {
    // Place the frame (motion model, homography, reference keyframe: the first that finds enough
    // matches), then confirm against the local map. With homography tracking, a placement the
    // local map does not confirm gives way to the next method (a wrong constant-velocity guess
    // under jitter can still find 20 chance matches).
    const int gap = last_frame_ ? frame_index - last_frame_->frame_index : 0;
    // Right after untracked frames the pose comes from a weaker prediction: demand more support.
    const int needed = consecutive_failures_ > 0 ? options_.min_inliers_after_failure : options_.min_inliers;
    const bool retry = options_.homography_tracking;
    bool placed = false;
    const auto attempt = [&](const char* method, const std::function<bool()>& place) {
      if (ok || (placed && !retry)) return;
      const double t0 = step.ElapsedMs();
      placed = place();
      const double t1 = step.ElapsedMs();
      result.timings.frame_to_frame += t1 - t0;
      if (!placed) return;
      ok = TrackLocalMap(&frame, needed);
      result.timings.local_map += step.ElapsedMs() - t1;
      if (ok) result.tracked_by = method;
    };
    int motion_inliers = 0;
    if (velocity_ && last_frame_ && gap >= 1) {
      Rigid3d predicted = *last_frame_->cam_from_world;
      for (int i = 0; i < gap; ++i) predicted = *velocity_ * predicted;
      attempt("motion model", [&] { return (motion_inliers = TrackWithMotionModel(&frame, predicted)) > 0; });
    }
    if (ok && retry && motion_inliers < kWeakMotionModel * last_frame_->CountTracked()) {
      // The motion model kept few of the last frame's points: a wrong guess that chance matches
      // confirmed, or a right one under a shaking camera. The homography decides: the placement
      // the local map supports better stays.
      const Frame motion_placed = frame;
      const KeyframeId motion_reference = reference_keyframe_;
      const int motion_tracked = frame.CountTracked();
      ok = false;
      attempt("homography", [&] { return TrackWithHomography(&frame); });
      if (!ok || frame.CountTracked() <= motion_tracked) {
        frame = motion_placed;
        reference_keyframe_ = motion_reference;
        ok = true;
        result.tracked_by = "motion model";
      }
    }
    if (options_.homography_tracking && last_frame_) attempt("homography", [&] { return TrackWithHomography(&frame); });
    attempt("reference keyframe", [&] { return TrackReferenceKeyframe(&frame); });
    if (!ok) {
      result.reason = pose_diverged_ ? TrackingReason::kPoseDiverged : TrackingReason::kTooFewMatches;
      if (!placed) {
        why = pose_diverged_ ? "pose optimization diverged" : "too few matches with the last frame and the reference keyframe";
      } else {
        why = pose_diverged_ ? "pose optimization against the local map diverged"
                             : std::to_string(frame.CountTracked()) + " local map points tracked, need " + std::to_string(needed);
      }
    }
  }
  const double before_keyframe = step.ElapsedMs();
  if (ok) {
    // A frame right after untracked ones does not become a keyframe: its pose is the least sure.
    OnTracked(&frame, &output, /*may_make_keyframe=*/consecutive_failures_ == 0);
  } else {
    ++consecutive_failures_;
    result.detail = why;
    if (consecutive_failures_ >= options_.lost_after_frames) {
      result.state = TrackingState::kLost;
      result.detail = "lost after " + std::to_string(consecutive_failures_) + " untracked frames (" + why + ")";
      if (policy_ == LossPolicy::kNewSubmap) {
        result.detail += "; submap closed, a new one starts";
        output.closed_submap = CloseSubmap();
      } else {
        result.detail += "; relocalizing in the kept map";
        lost_ = true;
        last_frame_.reset();
        velocity_.reset();
      }
    } else {
      result.state = TrackingState::kSkipped;
    }
  }
  result.submap_keyframes = map_ ? static_cast<int>(map_->num_keyframes()) : 0;
  result.timings.keyframe = step.ElapsedMs() - before_keyframe;
  return output;
}

void Tracking::OnTracked(Frame* frame, Output* output, bool may_make_keyframe) {
  TrackResult& result = output->result;
  const int gap = last_frame_ ? frame->frame_index - last_frame_->frame_index : 0;
  if (last_frame_ && gap == 1) {
    velocity_ = *frame->cam_from_world * last_frame_->cam_from_world->Inverse();
  } else {
    velocity_.reset();  // after a skipped frame the motion model is not trusted
  }
  const int inliers = frame->CountTracked();
  typical_sharpness_ = typical_sharpness_ > 0 ? 0.9 * typical_sharpness_ + 0.1 * frame->sharpness : frame->sharpness;
  consecutive_failures_ = 0;
  if (may_make_keyframe && NeedKeyframe(*frame, inliers)) {
    output->new_keyframes.push_back(CreateKeyframe(*frame));
    result.is_keyframe = true;
  }
  for (size_t i = 0; i < frame->size(); ++i) {
    if (frame->outlier[i]) frame->points[i] = MapPointId();
  }
  result.state = TrackingState::kOk;
  result.reason = TrackingReason::kNone;
  result.submap = map_->id();
  result.cam_from_submap = frame->cam_from_world;
  result.num_tracked_points = inliers;
  result.reference_keyframe = reference_keyframe_;
  if (const Keyframe* reference = map_->FindKeyframe(reference_keyframe_)) {
    result.cam_from_reference = *frame->cam_from_world * reference->cam_from_world.Inverse();
  }
  result.submap_keyframes = static_cast<int>(map_->num_keyframes());
  last_frame_ = std::move(*frame);
}

bool Tracking::Relocalize(Frame* frame, Output* output) {
  AdoptKeyframeBow(/*wait=*/true);  // every keyframe in the database
  ComputeBow(frame);
  // The kept map (relocalize policy), or every closed submap while a new one initializes.
  std::function<bool(int64_t)> accept;
  if (map_) {
    const int64_t current = map_->id().value;
    accept = [current](int64_t submap) { return submap == current; };
  }
  std::vector<KeyframeDatabase::Candidate> candidates = database_.Query(frame->bow, accept);
  if (candidates.empty()) return false;
  int most_common = 0;
  for (const auto& c : candidates) most_common = std::max(most_common, c.common_words);
  candidates.erase(std::remove_if(candidates.begin(), candidates.end(),
                                  [&](const auto& c) { return c.common_words < 0.8 * most_common; }),
                   candidates.end());
  std::sort(candidates.begin(), candidates.end(), [](const auto& a, const auto& b) { return a.score > b.score; });
  if (static_cast<int>(candidates.size()) > options_.relocalization_candidates) candidates.resize(options_.relocalization_candidates);
  const bool reopening = !map_;
  for (const auto& candidate : candidates) {
    if (!RelocalizeAgainst(frame, KeyframeId(candidate.keyframe_id))) continue;
    ++relocalizations_;
    lost_ = false;
    last_frame_.reset();
    velocity_.reset();
    ResetInitialization();
    OnTracked(frame, output, /*may_make_keyframe=*/false);
    TrackResult& result = output->result;
    result.relocalized = true;
    result.detail = std::string(reopening ? "relocalized into closed submap " : "relocalized in submap ") +
                    SubmapName(result.submap) + " at keyframe " + std::to_string(IndexOf(KeyframeId(candidate.keyframe_id))) +
                    " with " + std::to_string(result.num_tracked_points) + " points";
    if (reopening) output->reopened_submap = result.submap;
    return true;
  }
  return false;
}

bool Tracking::RelocalizeAgainst(Frame* frame, KeyframeId candidate) {
  const bool reopened = !map_;
  if (reopened) ReopenSubmap(SubmapOf(candidate));
  const auto give_up = [&]() {
    if (reopened) ShelveCurrentSubmap();
    return false;
  };
  const Keyframe* keyframe = map_ ? map_->FindKeyframe(candidate) : nullptr;
  if (!keyframe) return give_up();
  frame->points.assign(frame->size(), MapPointId());
  frame->outlier.assign(frame->size(), 0);
  const int matches = options_.reference_matching == "bow" ? SearchByBow(*keyframe, frame, *map_, 0.75)
                                                           : SearchByIndex(*keyframe, frame, *map_, FrameIndex(*frame), 0.75);
  if (matches < 15 || !PoseFromMatches(frame)) return give_up();
  reference_keyframe_ = candidate;
  if (!TrackLocalMap(frame, options_.relocalization_min_inliers)) return give_up();
  return true;
}

Tracking::Output Tracking::Initialize(Frame frame) {
  Output output;
  TrackResult& result = output.result;
  result.state = TrackingState::kInitializing;
  result.reason = TrackingReason::kInitFailed;
  result.num_features = static_cast<int>(frame.size());
  if (static_cast<int>(frame.size()) <= options_.init_min_features) {
    ResetInitialization();
    result.reason = TrackingReason::kTooFewFeatures;
    result.detail = std::to_string(frame.size()) + " features, initialization needs " + std::to_string(options_.init_min_features);
    return output;
  }
  if (!init_reference_) {
    init_previous_ = frame.undistorted;
    init_reference_ = std::move(frame);
    result.detail = "reference frame set, waiting for parallax";
    return output;
  }
  std::vector<int> matches;
  const int count = SearchForInitialization(*init_reference_, frame, &init_previous_, &matches, options_.init_window_px);
  if (count < options_.init_min_matches) {
    result.reason = TrackingReason::kTooFewMatches;
    result.detail = std::to_string(count) + " matches with the reference frame; it is replaced by this frame";
    init_previous_ = frame.undistorted;
    init_reference_ = std::move(frame);
    return output;
  }
  std::vector<Eigen::Vector2d> p1, p2;
  std::vector<int> index_of;
  for (size_t i = 0; i < matches.size(); ++i) {
    if (matches[i] < 0) continue;
    p1.push_back(init_reference_->undistorted[i]);
    p2.push_back(frame.undistorted[matches[i]]);
    index_of.push_back(static_cast<int>(i));
  }
  std::string why;
  const auto two_view = InitializeTwoView(p1, p2, intrinsics_, options_.initialization, &why);
  if (!two_view) {
    result.detail = why;
    return output;
  }
  // Expand the per-match result back to reference feature indices.
  TwoViewResult expanded = *two_view;
  expanded.points_in_cam1.assign(init_reference_->size(), Eigen::Vector3d::Zero());
  expanded.triangulated.assign(init_reference_->size(), 0);
  for (size_t m = 0; m < index_of.size(); ++m) {
    expanded.points_in_cam1[index_of[m]] = two_view->points_in_cam1[m];
    expanded.triangulated[index_of[m]] = two_view->triangulated[m];
  }
  if (!CreateInitialMap(&frame, matches, expanded, &output, &why)) {
    result.detail = why;
    ResetInitialization();
    return output;
  }
  result.state = TrackingState::kOk;
  result.reason = TrackingReason::kNone;
  result.submap = map_->id();
  result.cam_from_submap = frame.cam_from_world;
  result.num_tracked_points = frame.CountTracked();
  result.is_keyframe = true;
  typical_sharpness_ = frame.sharpness;
  result.reference_keyframe = reference_keyframe_;
  result.cam_from_reference = Rigid3d();
  result.submap_keyframes = static_cast<int>(map_->num_keyframes());
  result.detail = std::string("initialized from ") + (two_view->used_homography ? "a homography" : "an essential matrix") +
                  " with " + std::to_string(two_view->num_triangulated) + " points";
  last_frame_ = std::move(frame);
  return output;
}

bool Tracking::CreateInitialMap(Frame* frame, const std::vector<int>& matches, const TwoViewResult& two_view, Output* output,
                                std::string* why) {
  const SubmapId submap = MakeSubmapId(options_.agent_number, next_submap_number_);
  auto map = std::make_unique<Map>(submap, pyramid_, 0);
  Frame& reference = *init_reference_;
  ComputeBow(&reference);
  ComputeBow(frame);
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
  BundleAdjust(map.get(), {id1}, {id0}, intrinsics_, ba);
  const double median_depth = map->MedianDepth(id0);
  const int tracked = map->FindKeyframe(id1)->CountPoints();
  if (median_depth <= 0 || tracked < options_.init_min_matches) {
    *why = "initial map rejected: median depth " + std::to_string(median_depth) + ", " + std::to_string(tracked) + " points";
    return false;
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
  map_ = std::move(map);
  ++next_submap_number_;
  next_keyframe_index_ = 2;
  frame->cam_from_world = kf1->cam_from_world;
  frame->points = kf1->points;
  frame->outlier.assign(frame->size(), 0);
  reference_keyframe_ = id1;
  last_keyframe_frame_index_ = frame->frame_index;
  velocity_.reset();
  consecutive_failures_ = 0;
  output->new_keyframes = {*map_->FindKeyframe(id0), *kf1};
  AddToDatabase(*map_->FindKeyframe(id0));
  AddToDatabase(*kf1);
  for (const auto& [id, point] : map_->points()) {
    MapPoint copy = point;
    copy.observations.clear();
    output->new_points.push_back(copy);
  }
  last_keyframe_sent_ = id1;
  ResetInitialization();
  return true;
}

int Tracking::OptimizeFramePose(Frame* frame, bool discard_outliers) {
  std::vector<PoseObservation> observations;
  std::vector<int> features;
  for (size_t i = 0; i < frame->size(); ++i) {
    if (!frame->points[i].valid()) continue;
    const MapPoint* point = map_->FindPoint(frame->points[i]);
    if (!point) {
      frame->points[i] = MapPointId();
      continue;
    }
    observations.push_back({frame->undistorted[i], point->position, pyramid_.inverse_sigma2[frame->keypoints[i].octave]});
    features.push_back(static_cast<int>(i));
  }
  if (observations.size() < 3) return 0;
  const PoseOptimizerResult optimized = OptimizePose(observations, *frame->cam_from_world, intrinsics_);
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

int Tracking::TrackWithMotionModel(Frame* frame, const Rigid3d& predicted) {
  frame->cam_from_world = predicted;
  std::fill(frame->points.begin(), frame->points.end(), MapPointId());
  int matches = SearchByProjection(frame, *last_frame_, *map_, intrinsics_, 15.0);
  if (matches < 20) {
    std::fill(frame->points.begin(), frame->points.end(), MapPointId());
    matches = SearchByProjection(frame, *last_frame_, *map_, intrinsics_, 30.0);
  }
  if (matches < 20) return 0;
  const int inliers = OptimizeFramePose(frame, true);
  return inliers >= 10 ? inliers : 0;
}

const DescriptorIndex& Tracking::FrameIndex(const Frame& frame) {
  if (!frame_index_ || frame_index_of_ != frame.frame_index || frame_index_->size() != static_cast<int>(frame.size())) {
    // LSH for the homography's matching when the reference keyframe goes by bag of words.
    const DescriptorSearch search =
        options_.reference_matching == "bow" ? DescriptorSearch::kLsh : ParseDescriptorSearch(options_.reference_matching);
    frame_index_.emplace(frame.descriptors, search);
    frame_index_of_ = frame.frame_index;
  }
  return *frame_index_;
}

bool Tracking::PoseFromMatches(Frame* frame) {
  std::vector<PnpMatch> matches;
  std::vector<int> features;
  for (size_t i = 0; i < frame->size(); ++i) {
    const MapPoint* point = frame->points[i].valid() ? map_->FindPoint(frame->points[i]) : nullptr;
    if (!point) continue;
    matches.push_back({frame->undistorted[i], point->position, pyramid_.scale[frame->keypoints[i].octave]});
    features.push_back(static_cast<int>(i));
  }
  const std::optional<PnpResult> pnp = EstimatePoseRansac(matches, intrinsics_);
  if (!pnp) return false;
  for (size_t m = 0; m < features.size(); ++m) {
    if (!pnp->inlier[m]) frame->points[features[m]] = MapPointId();
  }
  frame->cam_from_world = pnp->cam_from_world;
  return OptimizeFramePose(frame, true) >= 10;
}

bool Tracking::TrackWithHomography(Frame* frame) {
  // Where the last frame's tracked features went, from descriptors alone (no pose needed).
  const Frame& last = *last_frame_;
  std::fill(frame->points.begin(), frame->points.end(), MapPointId());
  std::vector<char> tracked(last.size(), 0);
  for (size_t i = 0; i < last.size(); ++i) tracked[i] = last.points[i].valid() && !last.outlier[i];
  const std::vector<char> queried =
      options_.homography_roi_per_cell > 0 ? FeatureRichCells(last, tracked, options_.homography_roi_per_cell) : tracked;
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
  if (SearchAroundPredictions(frame, last, *map_, predicted, options_.homography_search_px) < 20) return false;
  return PoseFromMatches(frame);
}

bool Tracking::TrackReferenceKeyframe(Frame* frame) {
  const Keyframe* reference = map_->FindKeyframe(reference_keyframe_);
  if (!reference) {
    // The reference was culled: the newest keyframe serves.
    KeyframeId newest;
    for (const auto& [id, kf] : map_->keyframes()) newest = std::max(newest, id);
    reference_keyframe_ = newest;
    reference = map_->FindKeyframe(newest);
    if (!reference) return false;
  }
  std::fill(frame->points.begin(), frame->points.end(), MapPointId());
  int matches = 0;
  if (options_.reference_matching == "bow") {
    // Its bag of words may still be on the worker (adopting it adds or removes no keyframe).
    if (reference->bow.empty()) AdoptKeyframeBow(/*wait=*/true);
    ComputeBow(frame);
    matches = SearchByBow(*reference, frame, *map_);
  } else {
    matches = SearchByIndex(*reference, frame, *map_, FrameIndex(*frame));
  }
  if (matches < 15) return false;
  frame->cam_from_world = last_frame_ ? *last_frame_->cam_from_world : reference->cam_from_world;
  return OptimizeFramePose(frame, true) >= 10;
}

bool Tracking::TrackLocalMap(Frame* frame, int min_inliers) {
  // Local keyframes: those observing the frame's points, their best neighbours, children, parent.
  std::map<KeyframeId, int> counts;
  for (size_t i = 0; i < frame->size(); ++i) {
    if (!frame->points[i].valid() || frame->outlier[i]) continue;
    if (const MapPoint* point = map_->FindPoint(frame->points[i])) {
      for (const auto& [kf, feature] : point->observations) ++counts[kf];
    }
  }
  std::vector<std::pair<int, KeyframeId>> ranked;
  for (const auto& [kf, count] : counts) ranked.push_back({count, kf});
  std::sort(ranked.begin(), ranked.end(), [](const auto& a, const auto& b) { return a.first > b.first || (a.first == b.first && a.second < b.second); });
  std::set<KeyframeId> local;
  local_keyframes_.clear();
  const auto add = [&](KeyframeId id) {
    if (id.valid() && map_->FindKeyframe(id) && local.insert(id).second) local_keyframes_.push_back(id);
  };
  for (const auto& [count, kf] : ranked) {
    if (static_cast<int>(local_keyframes_.size()) >= kMaxLocalKeyframes) break;
    add(kf);
  }
  const size_t direct = local_keyframes_.size();
  for (size_t i = 0; i < direct && static_cast<int>(local_keyframes_.size()) < kMaxLocalKeyframes; ++i) {
    const Keyframe* kf = map_->FindKeyframe(local_keyframes_[i]);
    for (KeyframeId neighbour : map_->BestCovisible(kf->id, 10)) add(neighbour);
    for (KeyframeId child : kf->children) add(child);
    add(kf->parent);
  }
  if (!ranked.empty()) reference_keyframe_ = ranked.front().second;

  // Local points not yet matched, predicted in view, searched by projection.
  // Every id once, in the local keyframes' order (a std::set here took a third of the time).
  seen_points_.Clear(4 * frame->size());
  for (size_t i = 0; i < frame->size(); ++i) {
    if (frame->points[i].valid()) seen_points_.Insert(frame->points[i].value);
  }
  std::vector<MapPointId> candidates;
  for (KeyframeId id : local_keyframes_) {
    for (MapPointId p : map_->FindKeyframe(id)->points) {
      if (p.valid() && seen_points_.Insert(p.value)) candidates.push_back(p);
    }
  }
  std::vector<PointInView> in_view;
  for (MapPointId p : candidates) {
    const MapPoint* point = map_->FindPoint(p);
    PointInView view;
    if (point && PredictInView(*point, *frame->cam_from_world, intrinsics_, undistorter_.min_x(), undistorter_.min_y(),
                               undistorter_.max_x(), undistorter_.max_y(), pyramid_, &view)) {
      in_view.push_back(view);
    }
  }
  SearchByProjection(frame, in_view, *map_, 1.0);
  return OptimizeFramePose(frame, false) >= min_inliers;
}

bool Tracking::NeedKeyframe(const Frame& frame, int inliers) const {
  const Keyframe* reference = map_->FindKeyframe(reference_keyframe_);
  if (!reference) return true;
  const int min_observations = map_->num_keyframes() <= 2 ? 2 : 3;
  int reference_points = 0;
  for (MapPointId p : reference->points) {
    const MapPoint* point = p.valid() ? map_->FindPoint(p) : nullptr;
    if (point && static_cast<int>(point->observations.size()) >= min_observations) ++reference_points;
  }
  const int max_gap = options_.max_keyframe_gap > 0 ? options_.max_keyframe_gap : static_cast<int>(std::lround(fps_));
  const bool mapper_ready = MapperCaughtUp() || !mapper_connected_;
  const bool long_gap = frame.frame_index >= last_keyframe_frame_index_ + max_gap;
  const bool few_tracked = inliers < options_.keyframe_ratio * reference_points && inliers > 15;
  return (long_gap || mapper_ready) && few_tracked && mapper_ready;
}

Keyframe Tracking::CreateKeyframe(const Frame& frame) {
  const KeyframeId id = MakeKeyframeId(map_->id(), next_keyframe_index_++);
  Keyframe* keyframe = nullptr;
  if (keyframe_worker_ && frame.bow.empty()) {
    // The bag of words serves relocalization only (the mapper computes its own): off the frame loop.
    keyframe = &map_->AddKeyframe(KeyframeFromFrame(frame, id));
    keyframe_worker_->Submit([this, id, descriptors = frame.descriptors] {
      FinishedBow finished{id, {}, {}};
      finished.bow = vocabulary_->Transform(descriptors, &finished.features, kDirectIndexLevel);
      std::lock_guard<std::mutex> lock(finished_mutex_);
      finished_bow_.push_back(std::move(finished));
    });
  } else {
    Frame copy = frame;
    ComputeBow(&copy);
    keyframe = &map_->AddKeyframe(KeyframeFromFrame(copy, id));
    AddToDatabase(*keyframe);
  }
  map_->UpdateConnections(id);
  reference_keyframe_ = id;
  last_keyframe_frame_index_ = frame.frame_index;
  last_keyframe_sent_ = id;
  return *keyframe;
}

void Tracking::ApplyUpdate(const LocalMapUpdate& update) {
  Map* target = map_ && map_->id() == update.submap ? map_.get() : nullptr;
  for (auto& closed : closed_maps_) {
    if (!target && closed.map->id() == update.submap) target = closed.map.get();
  }
  if (!target) return;
  ApplyLocalMapUpdate(update, target);
  for (KeyframeId id : update.removed_keyframes) database_.Remove(id.value);
  if (update.last_keyframe.value > mapper_processed_.value) mapper_processed_ = update.last_keyframe;
  mapper_connected_ = true;
}

}  // namespace stitch
