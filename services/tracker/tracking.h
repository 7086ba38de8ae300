#pragma once
// The tracker's per-frame algorithm (no LCM here; TrackerService carries it over the bus).
// Monocular keyframe tracking as in ORB-SLAM2: two-view initialization, tracking with a
// constant-velocity model (falling back to the reference keyframe via bag of words), then
// against the local map, and keyframe decisions. It keeps its own copy of the current submap,
// which the mapper's updates refine. One owner thread; not thread-safe (it may run a worker
// thread of its own: keyframe_worker).
//
// Loss (docs/tracking-loss.md): `lost_after_frames` consecutive untracked frames make tracking
// lost; fewer are skipped. Then, by policy: kNewSubmap closes the submap and initializes a new
// one on the next usable frames; if that has not succeeded within `relocalize_closed_after_frames`
// it also tries to relocalize into the closed submaps (reopening the one it lands in); kRelocalize (ORB-SLAM2's behaviour, the baseline) keeps the map
// and discards frames until one relocalizes in it.

#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "stitch/estimators/bundle_adjustment.h"
#include "stitch/estimators/two_view.h"
#include "stitch/features/descriptor_index.h"
#include "stitch/features/keyframe_database.h"
#include "stitch/features/orb_extractor.h"
#include "stitch/features/vocabulary.h"
#include "stitch/map/local_map_update.h"
#include "stitch/map/map.h"
#include "stitch/util/flat_id_set.h"
#include "stitch/util/worker_thread.h"

namespace stitch {

struct TrackingOptions {
  OrbOptions orb;
  TwoViewOptions initialization;
  int init_min_features = 100;     // a frame needs this many features to take part in initialization
  int init_min_matches = 50;       // matches with the reference frame to keep it and attempt initialization
  int init_window_px = 100;        // search window around each feature's last match
  int min_inliers = 30;            // tracked points for a frame to count as tracked
  int min_inliers_after_failure = 30;  // ...right after an untracked frame (as ORB-SLAM after relocalization)
  int lost_after_frames = 3;       // consecutive untracked frames that make tracking lost
  double keyframe_ratio = 0.9;     // new keyframe when the frame tracks fewer than this x reference's points
  int max_keyframe_gap = 0;        // frames between keyframes at most (0: one second of frames)
  double min_relative_sharpness = 0.45;  // frames sharper than this x the recent tracked frames are tracked; others are blurred
  int relocalization_candidates = 8;    // keyframes tried per frame when relocalizing
  int relocalize_closed_after_frames = 20;  // submap policy: frames a new map tries to initialize before closed submaps are tried
  int relocalization_min_inliers = 50;  // tracked points that accept a relocalized pose
  // Matching against the reference keyframe and relocalization candidates, where no pose says
  // where to look: bow (the vocabulary's direct index), lsh or brute_force (DescriptorIndex).
  std::string reference_matching = "bow";
  // When the motion model fails: match the last frame's tracked features to this frame (LSH, or
  // brute force when reference_matching is brute_force), fit a homography, and search each point
  // around where it predicts (fast rotation, jitter; exact for a planar scene or a pure rotation).
  bool homography_tracking = true;
  double homography_threshold_px = 8;  // RANSAC inlier threshold of the homography, pixels
  double homography_search_px = 12;    // search radius around the homography's predictions, pixels at level 0
  // Region of interest for the homography's descriptor matching: the last frame is cut into 8x6
  // cells; only cells holding at least half the mean number of tracked features take part, each
  // with at most this many of its strongest (0: every tracked feature is matched). Off by
  // default: the same poses, and no measurable gain (docs/speed.md).
  int homography_roi_per_cell = 0;
  // A new keyframe's bag of words (for relocalization; the mapper computes its own) on a
  // background thread instead of in the frame loop.
  bool keyframe_worker = true;
  int agent_number = 0;            // high bits of every id this tracker makes
  int first_submap_number = 1;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("orb", orb, "feature extraction");
    v("initialization", initialization, "two-view map initialization");
    v("init_min_features", init_min_features, "features a frame needs to take part in initialization");
    v("init_min_matches", init_min_matches, "matches with the reference frame needed to attempt initialization");
    v("init_window_px", init_window_px, "initialization search window, pixels");
    v("min_inliers", min_inliers, "tracked points for a frame to count as tracked");
    v("min_inliers_after_failure", min_inliers_after_failure, "tracked points needed right after an untracked frame");
    v("lost_after_frames", lost_after_frames, "consecutive untracked frames that make tracking lost (one bad frame is skipped)");
    v("keyframe_ratio", keyframe_ratio, "new keyframe when tracking fewer than this fraction of the reference keyframe's points");
    v("max_keyframe_gap", max_keyframe_gap, "frames between keyframes at most (0: one second)");
    v("min_relative_sharpness", min_relative_sharpness, "a frame less sharp than this fraction of recent tracked frames is skipped as motion-blurred (0: off)");
    v("relocalize_closed_after_frames", relocalize_closed_after_frames, "submap policy: frames a new map tries to initialize alone before relocalization into closed submaps is tried too");
    v("relocalization_candidates", relocalization_candidates, "keyframes (by bag of words) tried per frame when relocalizing");
    v("relocalization_min_inliers", relocalization_min_inliers, "tracked points needed to accept a relocalized pose");
    v("reference_matching", reference_matching, "matching against the reference keyframe and relocalization candidates: bow (vocabulary direct index), lsh or brute_force");
    v("homography_tracking", homography_tracking, "when the motion model fails, track through a homography fitted to matches with the last frame (fast rotation, jitter)");
    v("homography_threshold_px", homography_threshold_px, "RANSAC inlier threshold of that homography, pixels");
    v("homography_search_px", homography_search_px, "search radius around the homography's predicted positions, pixels at level 0");
    v("homography_roi_per_cell", homography_roi_per_cell, "homography matching only from feature-rich cells of the last frame (8x6), at most this many strongest features each (0: all tracked features)");
    v("keyframe_worker", keyframe_worker, "compute new keyframes' bag of words (relocalization database) on a background thread, off the frame loop");
    v("agent_number", agent_number, "number of this aircraft in every id (0-32767)");
    v("first_submap_number", first_submap_number, "number of the first submap (1-65535)");
  }
  bool Check(std::string* why) const;
};

enum class TrackingState { kInitializing, kOk, kLost, kSkipped, kNotTracked };
// What the tracker does when tracking is lost.
enum class LossPolicy {
  kNewSubmap,   // close the submap, start a new one at once (stitch)
  kRelocalize,  // keep the map, discard frames until relocalized (ORB-SLAM2, the baseline)
};
// "submap" or "relocalize"; throws stitch::Error for anything else.
LossPolicy ParseLossPolicy(const std::string& name);
enum class TrackingReason {
  kNone,
  kTooFewFeatures,
  kTooFewMatches,
  kInitFailed,
  kPoseDiverged,
  kUndecodableFrame,
  kDropped,
  kNoTracker,
  kMotionBlur,
  kNotRelocalized,
};

const char* TrackingStateName(TrackingState state);
const char* TrackingReasonName(TrackingReason reason);

// Where a frame's time went, milliseconds.
struct TrackTimings {
  double extraction = 0;   // ORB features and their undistortion
  double frame_to_frame = 0;  // motion model, homography or reference keyframe: matching and pose
  double local_map = 0;    // local map: selection, projection search, pose
  double keyframe = 0;     // keyframe decision and creation
  double total = 0;
};

struct TrackResult {
  TrackingState state = TrackingState::kNotTracked;
  TrackingReason reason = TrackingReason::kNone;
  std::string detail;
  SubmapId submap;
  std::optional<Rigid3d> cam_from_submap;
  KeyframeId reference_keyframe;             // for re-composing the pose with refined keyframes
  std::optional<Rigid3d> cam_from_reference;
  int num_features = 0;
  int num_tracked_points = 0;
  bool is_keyframe = false;
  bool relocalized = false;  // the pose comes from relocalization (in a kept or reopened submap)
  // How the frame was first placed: "motion model", "homography", "reference keyframe", ...
  const char* tracked_by = "";
  int submap_keyframes = 0;
  TrackTimings timings;
};

class Tracking {
 public:
  struct Output {
    TrackResult result;
    std::vector<Keyframe> new_keyframes;  // to send to the mapper, in order
    std::vector<MapPoint> new_points;     // created with new_keyframes.front() (the initial map)
    std::optional<SubmapId> closed_submap;
    std::optional<SubmapId> reopened_submap;  // relocalized into this closed submap, now current again
  };

  // `vocabulary` must outlive the tracker.
  Tracking(const TrackingOptions& options, const Camera& camera, const Vocabulary* vocabulary, double fps,
           LossPolicy policy = LossPolicy::kNewSubmap);
  ~Tracking();

  Output Track(const cv::Mat& image, int frame_index, int64_t t_ns);
  // Applies the mapper's changes to the tracker's copy of the submap (current or closed).
  void ApplyUpdate(const LocalMapUpdate& update);
  // Ends the current submap now (e.g. at shutdown); returns its id if there was one.
  std::optional<SubmapId> CloseSubmap();

  // The mapper has processed every keyframe sent so far.
  bool MapperCaughtUp() const { return !last_keyframe_sent_.valid() || mapper_processed_.value >= last_keyframe_sent_.value; }
  KeyframeId last_keyframe_sent() const { return last_keyframe_sent_; }
  void SetMapperConnected(bool connected) { mapper_connected_ = connected; }
  bool mapper_connected() const { return mapper_connected_; }
  int submaps_closed() const { return submaps_closed_; }
  int relocalizations() const { return relocalizations_; }
  // Number the next new submap gets (persisted by the service so ids stay unique across restarts).
  int next_submap_number() const { return next_submap_number_; }
  bool lost() const { return lost_; }
  const Map* map() const { return map_.get(); }
  const Camera& camera() const { return camera_; }

 private:
  Output TrackFrame(const cv::Mat& image, int frame_index, int64_t t_ns);
  Output Initialize(Frame frame);
  void OnTracked(Frame* frame, Output* output, bool may_make_keyframe);
  void AddToDatabase(const Keyframe& keyframe);
  // Keyframes whose bag of words the worker has finished get it, and enter the database;
  // `wait`: first wait for the worker to finish all.
  void AdoptKeyframeBow(bool wait);
  bool CreateInitialMap(Frame* frame, const std::vector<int>& matches, const TwoViewResult& two_view,
                        Output* output, std::string* why);
  // Points kept after the pose optimization (0: failed).
  int TrackWithMotionModel(Frame* frame, const Rigid3d& predicted);
  bool TrackWithHomography(Frame* frame);
  // The frame's descriptor index (built on first use in a frame).
  const DescriptorIndex& FrameIndex(const Frame& frame);
  // Pose from the frame's 2D-3D matches: PnP RANSAC, then optimization; outliers dropped.
  bool PoseFromMatches(Frame* frame);
  bool TrackReferenceKeyframe(Frame* frame);
  bool TrackLocalMap(Frame* frame, int min_inliers);
  int OptimizeFramePose(Frame* frame, bool discard_outliers);
  // Localizes `frame` from scratch in the current map (relocalize policy) or, while a new map
  // initializes, in the closed submaps (reopening the one it lands in). Sets the tracking state.
  bool Relocalize(Frame* frame, Output* output);
  bool RelocalizeAgainst(Frame* frame, KeyframeId candidate);
  void ReopenSubmap(SubmapId id);
  void ShelveCurrentSubmap();  // back among the closed ones (a reopening that did not hold)
  bool NeedKeyframe(const Frame& frame, int inliers) const;
  Keyframe CreateKeyframe(const Frame& frame);
  void ComputeBow(Frame* frame) const;
  void ResetInitialization();
  void StartNewSubmap();

  TrackingOptions options_;
  Camera camera_;
  PinholeIntrinsics intrinsics_;
  const Vocabulary* vocabulary_;
  double fps_;
  ScalePyramid pyramid_;
  Undistorter undistorter_;
  OrbExtractor extractor_;
  OrbExtractor init_extractor_;  // twice the features, for initialization (as ORB-SLAM)

  LossPolicy policy_;
  std::unique_ptr<Map> map_;  // the current submap; empty until initialized
  struct ClosedSubmap {
    std::unique_ptr<Map> map;
    uint32_t next_keyframe_index = 0;
  };
  std::vector<ClosedSubmap> closed_maps_;
  KeyframeDatabase database_;  // keyframes of the current and closed submaps, for relocalization
  int next_submap_number_;
  uint32_t next_keyframe_index_ = 0;
  int submaps_closed_ = 0;
  int relocalizations_ = 0;
  bool lost_ = false;           // relocalize policy: the map is kept but the camera is not in it
  int frames_initializing_ = 0;  // frames since the last submap closed (submap policy)
  bool pose_diverged_ = false;  // a pose optimization of this frame failed to converge
  TrackingState last_state_ = TrackingState::kNotTracked;

  std::optional<Frame> init_reference_;
  std::vector<Eigen::Vector2d> init_previous_;

  std::optional<Frame> last_frame_;          // last tracked frame
  std::optional<Rigid3d> velocity_;          // cam_from_world(k) * world_from_cam(k - 1)
  KeyframeId reference_keyframe_;
  int last_keyframe_frame_index_ = -1;
  int consecutive_failures_ = 0;
  double typical_sharpness_ = 0;  // running average over tracked frames
  std::vector<KeyframeId> local_keyframes_;
  FlatIdSet seen_points_;  // TrackLocalMap's scratch, kept to reuse its table
  struct FinishedBow {
    KeyframeId keyframe;
    BowVector bow;
    FeatureVector features;
  };
  std::unique_ptr<WorkerThread> keyframe_worker_;  // with options_.keyframe_worker
  std::mutex finished_mutex_;
  std::vector<FinishedBow> finished_bow_;  // from the worker, not yet adopted
  std::optional<DescriptorIndex> frame_index_;  // of the frame being tracked
  int frame_index_of_ = -1;                     // ...its frame number

  KeyframeId last_keyframe_sent_;
  KeyframeId mapper_processed_;
  bool mapper_connected_ = true;
};

}  // namespace stitch
