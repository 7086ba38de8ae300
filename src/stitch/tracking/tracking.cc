#include "stitch/tracking/tracking.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iterator>
#include <limits>
#include <unordered_map>

#include "stitch/tracking/keyframe_decision.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "stitch/util/options.h"
#include "stitch/util/time.h"

namespace stitch {
namespace {

OrbOptions TwiceTheFeatures(OrbOptions options) {
  options.num_features *= 2;
  return options;
}

}  // namespace

Tracking::Tracking(const TrackingOptions& options, const Camera& camera, const Vocabulary* vocabulary, double fps,
                   LossPolicy policy)
    : options_(options),
      geometry_(camera, ScalePyramid::From(options.orb)),
      vocabulary_(vocabulary),
      fps_(fps > 0 ? fps : 30.0),
      extractor_(options.orb),
      init_extractor_(TwiceTheFeatures(options.orb)),
      policy_(options.localize_only ? LossPolicy::kRelocalize : policy),
      initializer_(options, &geometry_, vocabulary),
      placer_(options, &geometry_, vocabulary, [this] { AdoptKeyframeBow(/*wait=*/true); }),
      flow_(options.flow),
      relocalizer_(options, &placer_, vocabulary, [this] { AdoptKeyframeBow(/*wait=*/true); }),
      next_submap_number_(options.first_submap_number) {
  CheckOptions(options_, "tracker");
  if (!vocabulary_ || vocabulary_->empty()) throw Error("Tracking needs a vocabulary");
  if (options_.keyframe_worker) keyframe_bow_ = std::make_unique<KeyframeBowWorker>(vocabulary_);
  if (!options_.prior_map.empty()) {
    SavedMap saved = ReadMapFile(options_.prior_map, MakeSubmapId(kSavedMapAgent, 0));
    const size_t keyframes = saved.map.num_keyframes();
    if (const std::string why = UseSavedMap(std::move(saved)); !why.empty()) {
      if (options_.localize_only) throw Error(options_.prior_map + ": cannot localize in it: " + why);
      STITCH_LOG(WARNING) << "the saved map " << options_.prior_map << " is not used by the tracker: " << why
                          << " (the merger still merges the flight into it)";
    } else {
      STITCH_LOG(INFO) << "the saved map " << options_.prior_map << ": " << keyframes
                       << " keyframes to relocalize in from the first frame";
    }
  }
}

void Tracking::AdoptKeyframeBow(bool wait) {
  if (!keyframe_bow_) return;
  for (KeyframeBowWorker::Finished& finished : keyframe_bow_->Take(wait)) {
    Keyframe* keyframe = store_.FindKeyframe(finished.keyframe);
    if (!keyframe) continue;  // culled by the mapper meanwhile
    keyframe->bow = std::move(finished.bow);
    keyframe->bow_features = std::move(finished.features);
    store_.AddToDatabase(*keyframe);
  }
}

void Tracking::ForgetMotion() {
  last_frame_.reset();
  velocity_.reset();
  flow_.Clear();
}

std::optional<SubmapId> Tracking::CloseSubmap() {
  const std::optional<SubmapId> id = store_.CloseCurrent();
  if (!id) return std::nullopt;
  ++submaps_closed_;
  ForgetMotion();
  reference_keyframe_ = KeyframeId();
  consecutive_failures_ = 0;
  typical_sharpness_ = 0;
  lost_ = false;
  frames_initializing_ = 0;
  young_submap_started_at_ = -1;
  started_in_saved_ = SubmapId();
  saved_keyframe_copies_.clear();
  saved_point_copies_.clear();
  saved_followed_at_ = -1;
  initializer_.Reset();
  return id;
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
  } else if (!result.detail.empty()) {
    // Why a frame stays where it was (initialization waiting, relocalization failing): at debug.
    STITCH_LOG(DEBUG) << "frame " << frame_index << ": " << TrackingStateName(result.state) << ": " << result.detail;
  }
  return output;
}

Tracking::Output Tracking::TrackFrame(const cv::Mat& image, int frame_index, int64_t t_ns) {
  Output output;
  if (TryFollow(image, frame_index, t_ns, &output)) {
    ++followed_in_a_row_;
    return output;
  }
  output = TrackExtracted(image, frame_index, t_ns);
  // A frame extracted and tracked now is the flow's source for the frames after it.
  followed_in_a_row_ = 0;
  if (options_.flow.enabled && output.result.state == TrackingState::kOk && store_.current() && last_frame_ &&
      last_frame_->frame_index == frame_index) {
    flow_.KeepSource(image, *last_frame_);
  } else {
    flow_.Clear();
  }
  return output;
}

bool Tracking::TryFollow(const cv::Mat& image, int frame_index, int64_t t_ns, Output* output) {
  const Map* map = store_.current();
  if (!options_.flow.enabled || !flow_.has_source() || followed_in_a_row_ >= options_.flow.max_frames || !map ||
      lost_ || !last_frame_ || !velocity_ || consecutive_failures_ > 0 || !missed_.empty() ||
      young_submap_started_at_ >= 0) {
    return false;
  }
  const int gap = frame_index - last_frame_->frame_index;
  const Keyframe* reference = map->FindKeyframe(reference_keyframe_);
  if (gap < 1 || !reference) return false;
  // A frame an extracted one could make a keyframe of is extracted: this one must keep at least
  // the share of the reference's points below which a keyframe is made (the along-axis share for
  // a camera moving along its axis; the flow keeps at most the source's points).
  const int reference_points = ReferencePoints(*map, *reference);
  const auto needed = [&](double ratio) {
    const double share = std::min(1.0, ratio + options_.flow.keyframe_margin);
    return std::max(options_.min_inliers, static_cast<int>(std::ceil(share * reference_points)));
  };
  if (flow_.source_points() < needed(options_.keyframe_ratio)) return false;
  // Lucas-Kanade shifts its window but does not turn or warp it: a camera turning fast is extracted.
  if (RotationAngle(velocity_->rotation) * 180.0 / M_PI > options_.flow.max_turn_deg) return false;
  const Stopwatch clock;
  Rigid3d predicted = *last_frame_->cam_from_world;
  for (int i = 0; i < gap; ++i) predicted = *velocity_ * predicted;
  Frame frame = flow_.Follow(image, frame_index, t_ns, *map, predicted, geometry_.camera, geometry_.undistorter);
  if (static_cast<int>(frame.size()) < needed(options_.keyframe_ratio)) return false;
  frame.sharpness = ImageSharpness(image);
  if (Blurred(frame)) return false;
  if (options_.rolling_shutter_line_us > 0) {
    UnrollRollingShutter(&frame, *velocity_, velocity_interval_s_, options_.rolling_shutter_line_us * 1e-6, last_depth_,
                         geometry_.undistorter);
  }
  const double followed_ms = clock.ElapsedMs();
  const int inliers = placer_.OptimizeFramePose(*map, &frame, /*discard_outliers=*/true);
  KeyframeDecisionInput decision;
  decision.tracked_points = inliers;
  decision.reference_points = reference_points;
  if (options_.keyframe_ratio_along_axis != options_.keyframe_ratio && inliers >= needed(options_.keyframe_ratio)) {
    decision.motion_axis_angle_deg = MotionAxisAngleDeg(*reference, frame);
  }
  if (inliers < needed(KeyframeRatio(decision, options_))) return false;
  if (options_.keyframe_min_coverage > 0 &&
      TrackedCoverage(frame, geometry_.camera.width(), geometry_.camera.height()) < options_.keyframe_min_coverage) {
    return false;
  }
  TrackResult& result = output->result;
  result.num_features = static_cast<int>(frame.size());
  result.timings.extraction = followed_ms;
  result.timings.frame_to_frame = clock.ElapsedMs() - followed_ms;
  result.tracked_by = "optical flow";
  OnTracked(&frame, output, /*may_make_keyframe=*/false);
  return true;
}

Tracking::Output Tracking::TrackExtracted(const cv::Mat& image, int frame_index, int64_t t_ns) {
  if (!store_.current()) {
    return Initialize(MakeFrame(image, frame_index, t_ns, &init_extractor_, geometry_.undistorter));
  }
  const Stopwatch clock;
  Frame frame = MakeFrame(image, frame_index, t_ns, &extractor_, geometry_.undistorter);
  if (options_.rolling_shutter_line_us > 0 && velocity_ && !lost_) {
    UnrollRollingShutter(&frame, *velocity_, velocity_interval_s_, options_.rolling_shutter_line_us * 1e-6, last_depth_,
                         geometry_.undistorter);
  }
  Output output;
  TrackResult& result = output.result;
  result.timings.extraction = clock.ElapsedMs();
  result.submap = store_.current()->id();
  result.num_features = static_cast<int>(frame.size());
  if (lost_) return Relocalize(std::move(frame), std::move(output));
  // A young submap: is the camera back over a closed one, where the relocalize baseline would go on?
  std::optional<Frame> copy;
  if (young_submap_started_at_ >= 0) {
    const int age = frame_index - young_submap_started_at_;
    if (age > options_.return_to_closed_frames) {
      young_submap_started_at_ = -1;
    } else if (age % options_.return_to_closed_every == 0 && static_cast<int>(frame.size()) >= 20) {
      copy = frame;
    }
  }
  TrackInSubmap(std::move(frame), &output);
  // Not on a frame that made a keyframe of the young submap (it is sent already), nor after a
  // loss closed the young submap (Initialize relocalizes into the closed ones then).
  if (copy && store_.current() && output.new_keyframes.empty()) TryReturnToClosed(std::move(*copy), &output);
  return output;
}

Tracking::Output Tracking::Initialize(Frame frame) {
  if (options_.localize_only) {
    // No map of its own: the frame is placed in the saved map, or not at all.
    Output output;
    if (static_cast<int>(frame.size()) > options_.init_min_features &&
        TryRelocalize(&frame, &output, nullptr, /*saved_only=*/true)) {
      return output;
    }
    output.result.state = TrackingState::kNotTracked;
    output.result.reason = TrackingReason::kNotRelocalized;
    output.result.num_features = static_cast<int>(frame.size());
    output.result.detail = "not relocalized in the saved map (localize only)";
    return output;
  }
  // The method re-initializes at once. When the new map cannot initialize (no parallax: hover,
  // pure rotation), the camera may be back over a closed submap and relocalize there.
  ++frames_initializing_;
  const bool enough_features = static_cast<int>(frame.size()) > options_.init_min_features;
  const bool may_relocalize = (store_.has_closed() || store_.has_saved()) &&
                              frames_initializing_ > options_.relocalize_closed_after_frames && enough_features;
  const bool may_resume = !may_relocalize && !lost_from_.empty() && enough_features;
  // A saved map (stitch run --map) is tried first, from the first frame: where the camera sees
  // ground it mapped, the flight goes on in its frame rather than in a map of its own.
  const bool into_saved_first = store_.has_saved() && !may_relocalize && enough_features;
  std::optional<Frame> copy;  // to relocalize, or to place backward later
  if (may_relocalize || may_resume || into_saved_first || options_.retrack_missed_frames > 0) copy = frame;
  if (into_saved_first) {
    Frame attempt = frame;
    Output relocalized;
    if (TryRelocalize(&attempt, &relocalized, nullptr, /*saved_only=*/true)) return relocalized;
  }

  Output output;
  TrackResult& result = output.result;
  result.state = TrackingState::kInitializing;
  result.num_features = static_cast<int>(frame.size());
  Initializer::Result initialized =
      initializer_.Add(std::move(frame), MakeSubmapId(options_.agent_number, next_submap_number_));
  result.reason = initialized.reason;
  result.detail = initialized.detail;
  if (!initialized.map) {
    if (copy && (may_relocalize || may_resume)) {
      Output relocalized;
      if (TryRelocalize(&*copy, &relocalized, may_resume ? &lost_from_ : nullptr)) return relocalized;
    }
    if (copy) NoteMissed(std::move(*copy));
    return output;
  }
  lost_from_.clear();
  const SubmapId submap = initialized.map->id();
  const KeyframeId id0 = MakeKeyframeId(submap, 0), id1 = MakeKeyframeId(submap, 1);
  store_.StartCurrent(std::move(initialized.map), 2);
  ++next_submap_number_;
  Frame& placed = initialized.frame;
  young_submap_started_at_ = store_.has_closed() && options_.return_to_closed_frames > 0 ? placed.frame_index : -1;
  const Map& map = *store_.current();
  reference_keyframe_ = id1;
  last_keyframe_frame_index_ = placed.frame_index;
  velocity_.reset();
  consecutive_failures_ = 0;
  output.new_keyframes = {*map.FindKeyframe(id0), *map.FindKeyframe(id1)};
  store_.AddToDatabase(*map.FindKeyframe(id0));
  store_.AddToDatabase(*map.FindKeyframe(id1));
  for (const auto& [id, point] : map.points()) {
    MapPoint copy_without_observations = point;
    copy_without_observations.observations.clear();
    output.new_points.push_back(copy_without_observations);
  }
  NoteKeyframeSent(id0);
  NoteKeyframeSent(id1);

  result.state = TrackingState::kOk;
  result.submap = submap;
  result.cam_from_submap = placed.cam_from_world;
  result.num_tracked_points = placed.CountTracked();
  result.is_keyframe = true;
  typical_sharpness_ = placed.sharpness;
  result.reference_keyframe = reference_keyframe_;
  result.cam_from_reference = Rigid3d();
  result.submap_keyframes = static_cast<int>(map.num_keyframes());
  const Keyframe& kf0 = *map.FindKeyframe(id0);
  for (const Initializer::Result::PlacedFrame& earlier : initialized.earlier) {
    EarlierFrame e;
    e.frame_index = earlier.frame_index;
    e.t_ns = earlier.t_ns;
    TrackResult& r = e.result;
    r.state = TrackingState::kOk;
    r.detail = "placed once the map initialized at frame " + std::to_string(placed.frame_index);
    r.submap = submap;
    r.cam_from_submap = earlier.cam_from_world;
    r.reference_keyframe = id0;
    r.cam_from_reference = earlier.cam_from_world * kf0.cam_from_world.Inverse();
    r.num_features = earlier.num_features;
    r.num_tracked_points = earlier.tracked_points;
    r.is_keyframe = earlier.is_reference;
    r.tracked_by = "initialization";
    r.submap_keyframes = result.submap_keyframes;
    output.earlier_frames.push_back(std::move(e));
  }
  // Frames missed before the new map's first frame (a new submap after a loss): backward from it.
  if (!missed_.empty()) RetrackMissed(FrameFromKeyframe(kf0), &output);
  last_frame_ = std::move(placed);
  return output;
}

Tracking::Output Tracking::Relocalize(Frame frame, Output output) {
  // Relocalize policy: every frame is tried against the kept map, or discarded.
  if (frame.size() >= 20 && TryRelocalize(&frame, &output)) return output;
  NoteMissed(std::move(frame));
  TrackResult& result = output.result;
  result.state = TrackingState::kLost;
  result.reason = TrackingReason::kNotRelocalized;
  result.detail = "not relocalized in submap " + SubmapName(store_.current()->id()) + "; frame discarded";
  result.submap_keyframes = static_cast<int>(store_.current()->num_keyframes());
  return output;
}

void Tracking::TrackInSubmap(Frame frame, Output* output) {
  const Stopwatch clock;
  TrackResult& result = output->result;
  bool ok = false;
  std::string why;
  const bool blurred = Blurred(frame);
  if (frame.size() < 20) {
    why = std::to_string(frame.size()) + " features";
    result.reason = TrackingReason::kTooFewFeatures;
  } else if (blurred) {
    // A gust smears the image: matches on a blurred frame give wrong poses that look right.
    char text[96];
    std::snprintf(text, sizeof(text), "motion blur (sharpness %.1f, recent frames %.1f)", frame.sharpness,
                  typical_sharpness_);
    why = text;
    result.reason = TrackingReason::kMotionBlur;
  } else {
    // Right after untracked frames the pose comes from a weaker prediction: demand more support.
    const int needed = consecutive_failures_ > 0 ? options_.min_inliers_after_failure : options_.min_inliers;
    const FramePlacer::Placement placement = placer_.Place(
        &frame, *store_.current(), last_frame_ ? &*last_frame_ : nullptr, velocity_, needed, &reference_keyframe_);
    result.timings.frame_to_frame = placement.frame_to_frame_ms;
    result.timings.local_map = placement.local_map_ms;
    ok = placement.tracked;
    if (ok) {
      result.tracked_by = placement.tracked_by;
    } else {
      result.reason = placement.pose_diverged ? TrackingReason::kPoseDiverged : TrackingReason::kTooFewMatches;
      if (!placement.placed) {
        why = placement.pose_diverged ? "pose optimization diverged"
                                      : "too few matches with the last frame and the reference keyframe";
      } else {
        why = placement.pose_diverged
                  ? "pose optimization against the local map diverged"
                  : std::to_string(frame.CountTracked()) + " local map points tracked, need " + std::to_string(needed);
      }
    }
  }
  const double before_keyframe = clock.ElapsedMs();
  // Too few matches with the last frame and the reference keyframe, or a pose they diverged on
  // (a frame with features, not blurred): the whole submap is searched before the frame counts
  // as untracked.
  const bool placeable =
      result.reason == TrackingReason::kTooFewMatches || result.reason == TrackingReason::kPoseDiverged;
  if (!ok && options_.relocalize_untracked && placeable && TryRelocalize(&frame, output)) {
    result.timings.keyframe = clock.ElapsedMs() - before_keyframe;
    return;
  }
  if (ok) {
    // A frame right after untracked ones does not become a keyframe: its pose is the least sure.
    OnTracked(&frame, output, /*may_make_keyframe=*/consecutive_failures_ == 0);
    if (!HandOverIfFull(output) && last_frame_) FollowSavedMap(*last_frame_, output);
  } else {
    ++consecutive_failures_;
    result.detail = why;
    if (consecutive_failures_ >= options_.lost_after_frames) {
      result.state = TrackingState::kLost;
      result.detail = "lost after " + std::to_string(consecutive_failures_) + " untracked frames (" + why + ")";
      if (policy_ == LossPolicy::kNewSubmap) {
        result.detail += "; submap closed, a new one starts";
        std::set<KeyframeId> local_map = LocalMapKeyframes();
        output->closed_submap = CloseSubmap();
        DropClosedSubmaps(/*keep_last=*/true);
        lost_from_ = std::move(local_map);
      } else {
        result.detail += "; relocalizing in the kept map";
        lost_ = true;
        ForgetMotion();
      }
    } else {
      result.state = TrackingState::kSkipped;
    }
    NoteMissed(std::move(frame));
  }
  result.submap_keyframes = store_.current() ? static_cast<int>(store_.current()->num_keyframes()) : 0;
  result.timings.keyframe = clock.ElapsedMs() - before_keyframe;
}

void Tracking::OnTracked(Frame* frame, Output* output, bool may_make_keyframe) {
  TrackResult& result = output->result;
  Map& map = *store_.current();
  const int gap = last_frame_ ? frame->frame_index - last_frame_->frame_index : 0;
  if (last_frame_ && gap == 1) {
    velocity_ = *frame->cam_from_world * last_frame_->cam_from_world->Inverse();
    velocity_interval_s_ = (frame->t_ns - last_frame_->t_ns) * 1e-9;
  } else {
    velocity_.reset();  // after a skipped frame the motion model is not trusted
  }
  if (options_.rolling_shutter_line_us > 0) last_depth_ = FitInverseDepthPlane(map, *frame);
  const int inliers = frame->CountTracked();
  typical_sharpness_ = typical_sharpness_ > 0 ? 0.9 * typical_sharpness_ + 0.1 * frame->sharpness : frame->sharpness;
  consecutive_failures_ = 0;
  if (may_make_keyframe && !options_.localize_only) {
    KeyframeDecisionInput decision;
    decision.tracked_points = inliers;
    const Keyframe* reference = map.FindKeyframe(reference_keyframe_);
    decision.has_reference = reference != nullptr;
    decision.reference_points = reference ? ReferencePoints(map, *reference) : 0;
    if (reference && options_.keyframe_ratio_along_axis != options_.keyframe_ratio) {
      decision.motion_axis_angle_deg = MotionAxisAngleDeg(*reference, *frame);
    }
    const double ratio = KeyframeRatio(decision, options_);
    // Parallax matters only to a frame that would otherwise become a keyframe.
    if (reference && options_.keyframe_min_parallax_deg > 0 &&
        decision.tracked_points < ratio * decision.reference_points) {
      decision.parallax_deg = MedianParallaxDeg(map, *reference, *frame);
    }
    decision.frames_since_keyframe = frame->frame_index - last_keyframe_frame_index_;
    decision.mapper_ready = KeyframesInFlight() < options_.keyframes_in_flight || !mapper_connected_;
    // New ground in view matters only to a frame the ratio does not make a keyframe.
    if (reference && options_.keyframe_min_coverage > 0 &&
        decision.tracked_points >= ratio * decision.reference_points) {
      decision.tracked_coverage = TrackedCoverage(*frame, geometry_.camera.width(), geometry_.camera.height());
      if (decision.tracked_coverage >= 0 && decision.tracked_coverage < options_.keyframe_min_coverage) {
        decision.parallax_deg = MedianParallaxDeg(map, *reference, *frame);
      }
    }
    const bool need_keyframe = NeedKeyframe(decision, options_, fps_);
    STITCH_LOG(DEBUG) << "frame " << frame->frame_index << ": " << decision.tracked_points << " tracked of "
                      << decision.reference_points << " at the reference, parallax " << decision.parallax_deg
                      << " deg, moving " << decision.motion_axis_angle_deg << " deg off its axis, "
                      << decision.frames_since_keyframe << " frames since the last keyframe, mapper "
                      << (decision.mapper_ready ? "ready" : "busy") << (need_keyframe ? ": keyframe" : "");
    if (need_keyframe) {
      output->new_keyframes.push_back(CreateKeyframe(*frame));
      result.is_keyframe = true;
    }
  }
  DropOutliers(frame);
  result.state = TrackingState::kOk;
  result.reason = TrackingReason::kNone;
  result.submap = map.id();
  result.cam_from_submap = frame->cam_from_world;
  result.num_tracked_points = inliers;
  result.reference_keyframe = reference_keyframe_;
  if (const Keyframe* reference = map.FindKeyframe(reference_keyframe_)) {
    result.cam_from_reference = *frame->cam_from_world * reference->cam_from_world.Inverse();
  }
  result.submap_keyframes = static_cast<int>(map.num_keyframes());
  last_frame_ = std::move(*frame);
  if (!missed_.empty()) RetrackMissed(*last_frame_, output);
}

bool Tracking::Blurred(const Frame& frame) const {
  return typical_sharpness_ > 0 && frame.sharpness < options_.min_relative_sharpness * typical_sharpness_;
}

void Tracking::DropOutliers(Frame* frame) {
  for (size_t i = 0; i < frame->size(); ++i) {
    if (frame->outlier[i]) frame->points[i] = MapPointId();
  }
}

void Tracking::NoteMissed(Frame frame) {
  if (options_.retrack_missed_frames <= 0) return;
  if (frame.size() < 20) {
    missed_.clear();  // nothing to place it by: the chain backward ends here
    return;
  }
  std::fill(frame.points.begin(), frame.points.end(), MapPointId());
  std::fill(frame.outlier.begin(), frame.outlier.end(), 0);
  frame.cam_from_world.reset();
  missed_.push_back(std::move(frame));
  while (static_cast<int>(missed_.size()) > options_.retrack_missed_frames) missed_.pop_front();
}

void Tracking::RetrackMissed(const Frame& from, Output* output) {
  const Map* map = store_.current();
  if (!map || !from.cam_from_world) {
    missed_.clear();
    return;
  }
  // Backward, each frame from the one after it: the velocity cam_from_world(k) *
  // world_from_cam(k + 1) is unknown at first (the camera held still), then the last step's.
  const Frame* later = &from;
  std::optional<Rigid3d> velocity = Rigid3d();
  KeyframeId reference = reference_keyframe_;
  std::vector<EarlierFrame> placed;
  auto it = missed_.rbegin();
  while (it != missed_.rend() && it->frame_index >= from.frame_index) ++it;  // placed otherwise
  for (; it != missed_.rend(); ++it) {
    Frame& frame = *it;
    if (Blurred(frame)) break;
    const FramePlacer::Placement placement =
        placer_.Place(&frame, *map, later, velocity, options_.relocalization_min_inliers, &reference);
    if (!placement.tracked) break;
    DropOutliers(&frame);
    velocity = later->frame_index - frame.frame_index == 1 ? *frame.cam_from_world * later->cam_from_world->Inverse()
                                                           : Rigid3d();
    EarlierFrame e;
    e.frame_index = frame.frame_index;
    e.t_ns = frame.t_ns;
    TrackResult& r = e.result;
    r.state = TrackingState::kOk;
    r.detail = "placed backward from frame " + std::to_string(from.frame_index) + " (missed at first)";
    r.submap = map->id();
    r.cam_from_submap = frame.cam_from_world;
    r.reference_keyframe = reference;
    if (const Keyframe* keyframe = map->FindKeyframe(reference)) {
      r.cam_from_reference = *frame.cam_from_world * keyframe->cam_from_world.Inverse();
    }
    r.num_features = static_cast<int>(frame.size());
    r.num_tracked_points = frame.CountTracked();
    r.tracked_by = "backward";
    r.submap_keyframes = static_cast<int>(map->num_keyframes());
    placed.push_back(std::move(e));
    later = &frame;
  }
  const size_t missed = missed_.size();
  missed_.clear();
  if (placed.empty()) return;
  STITCH_LOG(INFO) << "frames " << placed.back().frame_index << "-" << placed.front().frame_index
                   << " placed backward from frame " << from.frame_index << " (" << placed.size() << " of " << missed
                   << " missed)";
  output->earlier_frames.insert(output->earlier_frames.begin(), std::make_move_iterator(placed.rbegin()),
                                std::make_move_iterator(placed.rend()));
}

bool Tracking::TryRelocalize(Frame* frame, Output* output, const std::set<KeyframeId>* only_at, bool saved_only) {
  const bool reopening = !store_.current();
  const RelocalizationScope scope = !reopening   ? RelocalizationScope::kCurrentSubmap
                                    : saved_only ? RelocalizationScope::kSavedMaps
                                                 : RelocalizationScope::kClosedSubmaps;
  const std::optional<KeyframeId> at = relocalizer_.Relocalize(frame, &store_, &reference_keyframe_, scope, 0, only_at);
  if (!at) return false;
  if (only_at) {
    // Back where it was lost (a blackout, a turn in place), or moved on to ground seen from afar?
    // A camera that moved on (wide parallax with the keyframe it relocalized at) maps the new
    // ground better in a new map of its own, which the merger places.
    const Map* map = store_.FindMap(SubmapOf(*at));
    const Keyframe* keyframe = map ? map->FindKeyframe(*at) : nullptr;
    const double parallax = keyframe ? MedianParallaxDeg(*map, *keyframe, *frame) : -1;
    if (parallax < 0 || parallax > options_.resume_max_parallax_deg) {
      char text[160];
      std::snprintf(text, sizeof(text),
                    "frame %d: relocalized where it was lost (submap %s) but moved on: parallax %.1f degrees; the new "
                    "map goes on initializing",
                    frame->frame_index, SubmapName(SubmapOf(*at)).c_str(), parallax);
      STITCH_LOG(INFO) << text;
      return false;
    }
  }
  lost_from_.clear();
  const bool into_saved = reopening && IsSavedMap(SubmapOf(*at));
  size_t copied = 0;
  if (into_saved && options_.localize_only) {
    store_.MakeSavedCurrent(SubmapOf(*at));
  } else if (into_saved) {
    // The saved map is not flown on: a new submap starts from copies of its local map here.
    LocalMapCopy copy = CopyLocalMap(*store_.FindMap(SubmapOf(*at)), reference_keyframe_, frame);
    copied = copy.keyframe_ids.size();
    started_in_saved_ = SubmapOf(*at);
    saved_keyframe_copies_ = copy.keyframe_ids;
    saved_point_copies_ = copy.point_ids;
    saved_followed_at_ = frame->frame_index;
    StartFromCopies(std::move(copy), frame, output);
  } else if (reopening) {
    store_.Reopen(SubmapOf(*at));
  }
  ++relocalizations_;
  lost_ = false;
  ForgetMotion();
  initializer_.Reset();
  OnTracked(frame, output, /*may_make_keyframe=*/false);
  TrackResult& result = output->result;
  result.relocalized = true;
  result.detail = std::string(reopening ? "relocalized into closed submap " : "relocalized in submap ") +
                  SubmapName(result.submap) + " at keyframe " + std::to_string(IndexOf(*at)) + " with " +
                  std::to_string(result.num_tracked_points) + " points";
  if (into_saved && options_.localize_only) {
    result.detail = "relocalized in the saved map at its keyframe " + std::to_string(IndexOf(*at)) + " with " +
                    std::to_string(result.num_tracked_points) + " points (localize only)";
  } else if (into_saved) {
    result.detail = "relocalized in the saved map at its keyframe " + std::to_string(IndexOf(*at)) + " with " +
                    std::to_string(result.num_tracked_points) + " points; submap " + SubmapName(result.submap) +
                    " starts from copies of " + std::to_string(copied) + " of its keyframes";
    STITCH_LOG(INFO) << "frame " << frame->frame_index << ": " << result.detail;
  } else if (reopening) {
    output->reopened_submap = result.submap;
  }
  return true;
}

void Tracking::TryReturnToClosed(Frame frame, Output* output) {
  KeyframeId reference;
  // Only into a submap larger than the young one: not back into another young one.
  const size_t young_keyframes = store_.current()->num_keyframes();
  const std::optional<KeyframeId> at =
      relocalizer_.Relocalize(&frame, &store_, &reference, RelocalizationScope::kClosedSubmaps, young_keyframes);
  if (!at) return;
  const int young_frames = frame.frame_index - young_submap_started_at_;
  Output returned;
  returned.result.num_features = output->result.num_features;
  returned.result.timings = output->result.timings;
  returned.earlier_frames = std::move(output->earlier_frames);  // placed in the young submap
  returned.closed_submap = CloseSubmap();                       // also ends the young window
  store_.Reopen(SubmapOf(*at));
  DropClosedSubmaps(/*keep_last=*/true);
  reference_keyframe_ = reference;
  ++relocalizations_;
  OnTracked(&frame, &returned, /*may_make_keyframe=*/false);
  returned.result.relocalized = true;
  returned.result.detail = "back in closed submap " + SubmapName(returned.result.submap) + " at keyframe " +
                           std::to_string(IndexOf(*at)) + " with " +
                           std::to_string(returned.result.num_tracked_points) + " points; submap " +
                           SubmapName(*returned.closed_submap) + " closed after " + std::to_string(young_frames) +
                           " frames, " + std::to_string(young_keyframes) + " keyframes";
  returned.reopened_submap = returned.result.submap;
  *output = std::move(returned);
}

std::set<KeyframeId> Tracking::LocalMapKeyframes() const {
  std::set<KeyframeId> keyframes;
  const Map* map = store_.current();
  if (!map || !options_.resume_where_lost) return keyframes;
  if (const Keyframe* reference = map->FindKeyframe(reference_keyframe_)) {
    keyframes.insert(reference->id);
    for (const auto& [id, shared] : reference->covisibility) keyframes.insert(id);
  }
  if (last_frame_) {
    for (MapPointId p : last_frame_->points) {
      const MapPoint* point = p.valid() ? map->FindPoint(p) : nullptr;
      if (!point) continue;
      for (const auto& [keyframe, feature] : point->observations) keyframes.insert(keyframe);
    }
  }
  return keyframes;
}

void Tracking::DropClosedSubmaps(bool keep_last) {
  for (SubmapId dropped : store_.DropClosedBeyond(static_cast<size_t>(options_.closed_keyframes_held), keep_last)) {
    STITCH_LOG(INFO) << "submap " << SubmapName(dropped)
                     << " dropped from the tracker (closed_keyframes_held); the mapper and the merger keep it";
  }
}

bool Tracking::HandOverIfFull(Output* output) {
  const Map& full = *store_.current();
  if (policy_ != LossPolicy::kNewSubmap || options_.submap_max_keyframes <= 0 ||
      static_cast<int>(full.num_keyframes()) < options_.submap_max_keyframes || output->result.is_keyframe ||
      !last_frame_) {
    return false;
  }
  const Keyframe* reference = full.FindKeyframe(reference_keyframe_);
  if (!reference) return false;
  AdoptKeyframeBow(/*wait=*/true);  // the copies carry their bags of words
  LocalMapCopy copy = CopyLocalMap(full, reference->id);
  // The frame goes on in the new submap: same pose, its points renamed.
  Frame frame = std::move(*last_frame_);
  const std::optional<Rigid3d> velocity = velocity_;
  const double sharpness = typical_sharpness_;
  const int last_keyframe = last_keyframe_frame_index_;
  const SubmapId closed = *CloseSubmap();  // `full` and `reference` are gone after
  const size_t copied = copy.keyframe_ids.size();
  StartFromCopies(std::move(copy), &frame, output);
  DropClosedSubmaps(/*keep_last=*/false);  // its local map goes on in the new submap
  const Map& current = *store_.current();
  velocity_ = velocity;
  typical_sharpness_ = sharpness;
  last_keyframe_frame_index_ = last_keyframe;
  output->closed_submap = closed;
  TrackResult& result = output->result;
  result.submap = current.id();
  result.reference_keyframe = reference_keyframe_;
  result.cam_from_reference =
      *frame.cam_from_world * current.FindKeyframe(reference_keyframe_)->cam_from_world.Inverse();
  result.num_tracked_points = frame.CountTracked();
  result.submap_keyframes = static_cast<int>(current.num_keyframes());
  result.detail = "submap " + SubmapName(closed) + " reached " + std::to_string(options_.submap_max_keyframes) +
                  " keyframes; continues in submap " + SubmapName(current.id()) + " from copies of its last " +
                  std::to_string(copied) + " keyframes and " + std::to_string(output->new_points.size()) + " points";
  STITCH_LOG(INFO) << "frame " << frame.frame_index << ": " << result.detail;
  last_frame_ = std::move(frame);
  return true;
}

Tracking::LocalMapCopy Tracking::CopyLocalMap(const Map& source, KeyframeId reference, const Frame* seen_by) const {
  std::vector<KeyframeId> window;
  if (seen_by) {
    // The keyframes that see most of the frame's points (the frame's local map, as tracking
    // builds it), the reference among them.
    std::map<KeyframeId, int> shared;
    for (MapPointId p : seen_by->points) {
      const MapPoint* point = p.valid() ? source.FindPoint(p) : nullptr;
      if (!point) continue;
      for (const auto& [keyframe, feature] : point->observations) ++shared[keyframe];
    }
    shared.erase(reference);
    std::vector<std::pair<int, KeyframeId>> ranked;
    for (const auto& [keyframe, count] : shared) ranked.push_back({count, keyframe});
    std::sort(ranked.begin(), ranked.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
    for (size_t i = 0; i < ranked.size() && static_cast<int>(i) + 1 < options_.handover_keyframes; ++i) {
      window.push_back(ranked[i].second);
    }
  } else {
    window = source.BestCovisible(reference, options_.handover_keyframes - 1);
  }
  window.push_back(reference);
  std::sort(window.begin(), window.end());  // in the order they were made
  LocalMapCopy copy;
  const SubmapId submap = MakeSubmapId(options_.agent_number, next_submap_number_);
  copy.map = std::make_unique<Map>(submap, source.pyramid());
  for (KeyframeId id : window) {
    copy.keyframe_ids[id] = MakeKeyframeId(submap, static_cast<uint32_t>(copy.keyframe_ids.size()));
  }
  copy.reference = copy.keyframe_ids.at(reference);
  // The points the copies observe, numbered in the order they are met.
  for (KeyframeId id : window) {
    for (MapPointId p : source.FindKeyframe(id)->points) {
      const MapPoint* point = p.valid() ? source.FindPoint(p) : nullptr;
      if (!point || copy.point_ids.count(p)) continue;
      MapPoint moved = *point;
      moved.id = copy.point_ids[p] = copy.map->NewPointId();
      moved.observations.clear();
      moved.reference_keyframe = moved.first_keyframe = copy.keyframe_ids.at(id);
      copy.map->AddPoint(std::move(moved));
    }
  }
  for (KeyframeId id : window) {
    Keyframe keyframe = UnlinkedCopy(*source.FindKeyframe(id));
    keyframe.id = copy.keyframe_ids.at(id);
    for (MapPointId& p : keyframe.points) p = copy.NewPointId(p);
    copy.map->AddKeyframe(std::move(keyframe));
  }
  for (KeyframeId id : window) copy.map->UpdateConnections(copy.keyframe_ids.at(id));
  return copy;
}

void Tracking::StartFromCopies(LocalMapCopy copy, Frame* frame, Output* output) {
  for (MapPointId& p : frame->points) p = copy.NewPointId(p);
  std::vector<KeyframeId> copies;
  for (const auto& [original, id] : copy.keyframe_ids) copies.push_back(id);
  std::sort(copies.begin(), copies.end());
  for (const auto& [id, point] : copy.map->points()) {
    MapPoint without_observations = point;
    without_observations.observations.clear();
    output->new_points.push_back(std::move(without_observations));
  }
  std::sort(output->new_points.begin(), output->new_points.end(),
            [](const MapPoint& a, const MapPoint& b) { return a.id < b.id; });
  store_.StartCurrent(std::move(copy.map), static_cast<uint32_t>(copies.size()));
  ++next_submap_number_;
  reference_keyframe_ = copy.reference;
  const Map& current = *store_.current();
  for (KeyframeId id : copies) {
    const Keyframe& keyframe = *current.FindKeyframe(id);
    store_.AddToDatabase(keyframe);
    output->new_keyframes.push_back(keyframe);
    NoteKeyframeSent(keyframe.id);
  }
}

void Tracking::FollowSavedMap(const Frame& frame, Output* output) {
  if (!started_in_saved_.valid() || options_.saved_map_follow_frames <= 0 || !frame.cam_from_world ||
      !output->new_keyframes.empty() || frame.frame_index - saved_followed_at_ < options_.saved_map_follow_frames) {
    return;
  }
  saved_followed_at_ = frame.frame_index;
  const Map* saved = store_.FindMap(started_in_saved_);
  Map* current = store_.current();
  if (!saved || !current) return;
  // The saved keyframe nearest the camera among those looking within 37 degrees of its way.
  const Eigen::Vector3d centre = frame.cam_from_world->CentreInWorld();
  const Eigen::Vector3d axis = frame.cam_from_world->rotation.conjugate() * Eigen::Vector3d::UnitZ();
  KeyframeId nearest;
  double nearest_m2 = std::numeric_limits<double>::infinity();
  for (const auto& [id, keyframe] : saved->keyframes()) {
    if ((keyframe.cam_from_world.rotation.conjugate() * Eigen::Vector3d::UnitZ()).dot(axis) < 0.8) continue;
    const double m2 = (keyframe.Centre() - centre).squaredNorm();
    if (m2 < nearest_m2) {
      nearest_m2 = m2;
      nearest = id;
    }
  }
  if (!nearest.valid()) return;
  std::vector<KeyframeId> window = saved->BestCovisible(nearest, options_.handover_keyframes - 1);
  window.push_back(nearest);
  std::sort(window.begin(), window.end());
  for (KeyframeId id : window) {
    if (saved_keyframe_copies_.count(id)) continue;
    Keyframe copy = UnlinkedCopy(*saved->FindKeyframe(id));
    copy.id = store_.NewKeyframeId();
    std::set<MapPointId> taken;  // a point the submap merged two copies into is observed once
    for (MapPointId& p : copy.points) {
      if (!p.valid()) continue;
      const MapPointId original = p;
      p = MapPointId();
      const auto known = saved_point_copies_.find(original);
      if (known != saved_point_copies_.end()) {
        if (current->FindPoint(known->second) && taken.insert(known->second).second) p = known->second;
        continue;
      }
      const MapPoint* point = saved->FindPoint(original);
      if (!point) continue;
      MapPoint moved = *point;
      moved.id = current->NewPointId();
      moved.observations.clear();
      moved.reference_keyframe = moved.first_keyframe = copy.id;
      saved_point_copies_[original] = moved.id;
      output->new_points.push_back(moved);
      p = moved.id;
      taken.insert(moved.id);
      current->AddPoint(std::move(moved));
    }
    saved_keyframe_copies_[id] = copy.id;
    const KeyframeId copy_id = copy.id;
    current->AddKeyframe(std::move(copy));
    current->UpdateConnections(copy_id);
    store_.AddToDatabase(*current->FindKeyframe(copy_id));
    output->new_keyframes.push_back(*current->FindKeyframe(copy_id));
    NoteKeyframeSent(copy_id);
  }
  if (!output->new_keyframes.empty()) {
    STITCH_LOG(DEBUG) << "frame " << frame.frame_index << ": " << output->new_keyframes.size()
                      << " keyframes of the saved map copied in around the camera";
  }
}

std::string Tracking::UseSavedMap(SavedMap saved) {
  // One camera, the flight's as the merger tells calibrations apart (Camera::Describe).
  if (saved.cameras.size() != 1 || saved.cameras[0].Describe() != geometry_.camera.Describe()) {
    return "its keyframes were seen by another camera than this flight's";
  }
  for (const auto& [id, unused] : saved.map.keyframes()) {
    Keyframe& keyframe = *saved.map.FindKeyframe(id);
    keyframe.undistorted.clear();
    for (const cv::KeyPoint& k : keyframe.keypoints) {
      keyframe.undistorted.push_back(geometry_.undistorter.Undistort(k.pt.x, k.pt.y));
    }
    keyframe.grid = FeatureGrid(keyframe.undistorted, geometry_.undistorter);
    keyframe.bow = vocabulary_->Transform(keyframe.descriptors, &keyframe.bow_features);
  }
  store_.AddSaved(std::make_unique<Map>(std::move(saved.map)));
  return "";
}

Keyframe Tracking::CreateKeyframe(const Frame& frame) {
  Map& map = *store_.current();
  const KeyframeId id = store_.NewKeyframeId();
  Keyframe* keyframe = nullptr;
  if (keyframe_bow_ && frame.bow.empty()) {
    // The bag of words serves relocalization only (the mapper computes its own): off the frame loop.
    keyframe = &map.AddKeyframe(KeyframeFromFrame(frame, id));
    keyframe_bow_->Submit(id, frame.descriptors);
  } else {
    Frame copy = frame;
    ComputeBow(*vocabulary_, &copy);
    keyframe = &map.AddKeyframe(KeyframeFromFrame(copy, id));
    store_.AddToDatabase(*keyframe);
  }
  map.UpdateConnections(id);
  reference_keyframe_ = id;
  last_keyframe_frame_index_ = frame.frame_index;
  NoteKeyframeSent(id);
  return *keyframe;
}

void Tracking::NoteKeyframeSent(KeyframeId id) {
  keyframes_sent_.push_back({id});
  if (keyframes_sent_.size() > 16) keyframes_sent_.pop_front();
}

int Tracking::KeyframesInFlight() const {
  return static_cast<int>(
      std::count_if(keyframes_sent_.begin(), keyframes_sent_.end(), [](const SentKeyframe& k) { return !k.answered; }));
}

bool Tracking::NewestKeyframePointsReceived() const {
  return keyframes_sent_.empty() || keyframes_sent_.back().answered || keyframes_sent_.back().points_received;
}

void Tracking::ApplyUpdate(const LocalMapUpdate& update, bool last_part) {
  if (!store_.Apply(update)) return;
  mapper_connected_ = true;
  if (!keyframes_sent_.empty() && !keyframes_sent_.back().points_received) {
    const KeyframeId newest = keyframes_sent_.back().id;
    keyframes_sent_.back().points_received =
        std::any_of(update.associations.begin(), update.associations.end(),
                    [&](const auto& association) { return association.first == newest; });
  }
  if (!last_part || !update.last_keyframe.valid()) return;
  // Keyframes are told apart by id, not ordered by it: those of a reopened submap have lower ids
  // than the newer submap's the mapper answered before.
  const auto answered = std::find_if(keyframes_sent_.begin(), keyframes_sent_.end(),
                                     [&](const SentKeyframe& k) { return k.id == update.last_keyframe; });
  if (answered == keyframes_sent_.end()) return;
  // The mapper takes keyframes in order: those sent before it are done too (or were lost).
  for (auto k = keyframes_sent_.begin(); k != std::next(answered); ++k) k->answered = true;
}

}  // namespace stitch
