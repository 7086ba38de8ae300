#pragma once
// The tracker's per-frame algorithm (no LCM here; TrackerService carries it over the bus):
// monocular keyframe tracking as in ORB-SLAM2, as a small state machine over parts with one job
// each:
//   - Initializer: two-view initialization of a new submap (initializer.h);
//   - FramePlacer: motion model, homography, reference keyframe, then the local map
//     (frame_placer.h);
//   - Relocalizer: a frame placed from scratch through the keyframe database (relocalizer.h);
//   - the keyframe decision (keyframe_decision.h);
//   - SubmapStore: the current and closed submaps and the keyframe database (submap_store.h);
//   - KeyframeBowWorker: new keyframes' bags of words off the frame loop (keyframe_bow.h).
// It keeps its own copy of the current submap, which the mapper's updates refine, and knows
// whether the mapper has taken the keyframes sent so far. One owner thread; not thread-safe
// (it may run a worker thread of its own: keyframe_worker).
//
// States: no current submap -> initializing (and at once relocalizing into the local map the
// camera was lost from, resuming that submap where the camera is back where it was lost; after
// relocalize_closed_after_frames frames, relocalizing into any closed submap, reopening the one
// it lands in); tracking; lost.
// `lost_after_frames` consecutive untracked frames make tracking lost; fewer are skipped. Then,
// by policy: kNewSubmap closes the submap and initializes a new one on the next usable frames;
// kRelocalize (ORB-SLAM2's behaviour, the baseline) keeps the map and discards frames until one
// relocalizes in it (docs/tracking-loss.md).

#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <unordered_map>
#include <vector>

#include <opencv2/core.hpp>

#include "stitch/features/orb_extractor.h"
#include "stitch/features/vocabulary.h"
#include "stitch/map/local_map_update.h"
#include "stitch/map/map.h"
#include "stitch/map/map_file.h"
#include "stitch/map/view_geometry.h"
#include "stitch/tracking/feature_flow.h"
#include "stitch/tracking/frame_placer.h"
#include "stitch/tracking/initializer.h"
#include "stitch/tracking/keyframe_bow.h"
#include "stitch/tracking/relocalizer.h"
#include "stitch/tracking/rolling_shutter.h"
#include "stitch/tracking/submap_store.h"
#include "stitch/tracking/tracking_options.h"
#include "stitch/tracking/tracking_result.h"

namespace stitch {

class Tracking {
 public:
  // A frame tracked before this one, placed only now (the frames a new map initialized from, and
  // frames missed before this one placed backward from it).
  struct EarlierFrame {
    int frame_index = -1;
    int64_t t_ns = 0;
    TrackResult result;
  };
  struct Output {
    TrackResult result;
    std::vector<EarlierFrame> earlier_frames;  // in frame order
    std::vector<Keyframe> new_keyframes;       // to send to the mapper, in order
    std::vector<MapPoint> new_points;          // created with new_keyframes.front() (the initial map)
    std::optional<SubmapId> closed_submap;
    std::optional<SubmapId> reopened_submap;  // relocalized into this closed submap, now current again
  };

  // `vocabulary` must outlive the tracker.
  Tracking(const TrackingOptions& options, const Camera& camera, const Vocabulary* vocabulary, double fps,
           LossPolicy policy = LossPolicy::kNewSubmap);

  Output Track(const cv::Mat& image, int frame_index, int64_t t_ns);
  // stitch run --map: a saved map (map_file.h) the camera relocalizes in while a new map
  // initializes (from the first frames of the flight, and after every loss). Where a frame lands
  // in it, a new submap starts with copies of the saved map's local map there (as at a handover:
  // the same poses, so in the saved map's frame), which the merger joins to the saved map on the
  // copies. Returns why not (empty: taken) where it cannot be used: a map of another camera.
  std::string UseSavedMap(SavedMap saved);
  // Applies the mapper's changes to the tracker's copy of the submap (current or closed).
  // `last_part`: whether this is the last part of its update (only that one says the mapper is
  // done with update.last_keyframe).
  void ApplyUpdate(const LocalMapUpdate& update, bool last_part = true);
  // Ends the current submap now (e.g. at shutdown); returns its id if there was one.
  std::optional<SubmapId> CloseSubmap();

  // The mapper has processed every keyframe sent so far.
  bool MapperCaughtUp() const { return KeyframesInFlight() == 0; }
  // Keyframes sent that the mapper has not answered yet (counted up to the last 16 sent).
  int KeyframesInFlight() const;
  KeyframeId last_keyframe_sent() const { return keyframes_sent_.empty() ? KeyframeId() : keyframes_sent_.back().id; }
  // The mapper has sent the points it triangulated for the newest keyframe sent (its early update,
  // or its whole answer); true when none was sent.
  bool NewestKeyframePointsReceived() const;
  void SetMapperConnected(bool connected) { mapper_connected_ = connected; }
  bool mapper_connected() const { return mapper_connected_; }
  int submaps_closed() const { return submaps_closed_; }
  int relocalizations() const { return relocalizations_; }
  // Number the next new submap gets (persisted by the service so ids stay unique across restarts).
  int next_submap_number() const { return next_submap_number_; }
  // The lowest number of a submap the tracker still holds: it dropped every one below (they get
  // no more keyframes; closed_keyframes_held).
  int first_submap_held() const { return store_.LowestNumberHeld(next_submap_number_); }
  bool lost() const { return lost_; }
  const Map* map() const { return store_.current(); }
  const Camera& camera() const { return geometry_.camera; }

 private:
  Output TrackFrame(const cv::Mat& image, int frame_index, int64_t t_ns);
  // Tracks the frame by following the flow source's points (feature_flow.h) where a frame
  // extracted from it could not become a keyframe; false (nothing changed) where it may, or the
  // flow does not hold.
  bool TryFollow(const cv::Mat& image, int frame_index, int64_t t_ns, Output* output);
  // Extracts the frame's features and tracks it (initializes, relocalizes, or tracks in the submap).
  Output TrackExtracted(const cv::Mat& image, int frame_index, int64_t t_ns);
  // No current submap: initialize a new one, or relocalize into a closed one.
  Output Initialize(Frame frame);
  // Lost (relocalize policy): relocalize in the kept submap or discard the frame.
  Output Relocalize(Frame frame, Output output);
  // Tracks against the current submap; handles failure and loss.
  void TrackInSubmap(Frame frame, Output* output);
  // A frame placed in the current submap: velocity, keyframe decision, result.
  void OnTracked(Frame* frame, Output* output, bool may_make_keyframe);
  // Relocalizes `frame` (in the current submap, or in a closed one which is reopened); on
  // success the frame is tracked and `output` says so.
  // `only_at` (optional): the keyframes it may land at.
  // `saved_only`: without a current submap, only into the saved maps.
  bool TryRelocalize(Frame* frame, Output* output, const std::set<KeyframeId>* only_at = nullptr,
                     bool saved_only = false);
  // The keyframes of the local map the camera is tracked in now (LostFrom's definition).
  std::set<KeyframeId> LocalMapKeyframes() const;
  // Submap policy, a young submap: relocalizes `frame` (a copy of the one tracked in it) into the
  // closed submaps; where it lands, the young submap closes, the closed one reopens and `output`
  // is replaced by the frame tracked there.
  void TryReturnToClosed(Frame frame, Output* output);
  // Keyframes whose bag of words the worker has finished get it, and enter the database;
  // `wait`: first wait for the worker to finish all.
  void AdoptKeyframeBow(bool wait);
  Keyframe CreateKeyframe(const Frame& frame);
  // A tracked frame of a submap that reached submap_max_keyframes: the submap closes and a new one
  // starts with copies of its local map (same poses), sent to the mapper in `output`; the frame
  // is tracked in the new one. False (nothing done) below the cap.
  bool HandOverIfFull(Output* output);
  // A new submap's start from copies of `source`'s local map around `reference` (it and its
  // handover_keyframes - 1 best covisible keyframes, their points, the same poses), numbered
  // for the next submap.
  struct LocalMapCopy {
    std::unique_ptr<Map> map;
    KeyframeId reference;                                     // the reference's copy
    std::unordered_map<KeyframeId, KeyframeId> keyframe_ids;  // source -> copy
    std::unordered_map<MapPointId, MapPointId> point_ids;     // source -> copy
    MapPointId NewPointId(MapPointId p) const {
      const auto it = p.valid() ? point_ids.find(p) : point_ids.end();
      return it == point_ids.end() ? MapPointId() : it->second;
    }
  };
  // `seen_by` (optional): the copies are the keyframes that see most of that frame's points (a
  // frame placed in `source`), not the reference's best covisible ones.
  LocalMapCopy CopyLocalMap(const Map& source, KeyframeId reference, const Frame* seen_by = nullptr) const;
  // The copy becomes the current submap (the reference its reference keyframe); its keyframes
  // and points go to the mapper in `output`; `frame`'s points are renamed to the copies'.
  void StartFromCopies(LocalMapCopy copy, Frame* frame, Output* output);
  // A submap started in a saved map, its camera tracked at `frame`: the saved keyframes around
  // the camera (the nearest looking the same way and its best covisible ones) that the submap
  // holds no copy of are copied in with their points and go to the mapper in `output`, so the
  // submap goes on over the saved map rather than only from the copies it started with. Every
  // saved_map_follow_frames frames, on frames that made no keyframe.
  void FollowSavedMap(const Frame& frame, Output* output);
  // Drops the closed submaps beyond closed_keyframes_held (after a submap closed); with
  // `keep_last`, the one just closed stays (lost: the camera may resume it).
  void DropClosedSubmaps(bool keep_last);
  // Forget the camera's motion (a new or reopened submap, or a lost camera).
  void ForgetMotion();
  // Less sharp than min_relative_sharpness of the recent tracked frames (a gust smears the image).
  bool Blurred(const Frame& frame) const;
  // A placed frame forgets the points its pose optimization set aside as outliers.
  static void DropOutliers(Frame* frame);
  // A frame that found no pose: kept for RetrackMissed (a frame too poor to track ends the chain
  // backward, so it empties the queue instead).
  void NoteMissed(Frame frame);
  // `from`, a frame of the current submap placed just now (the last frame, or a new map's first),
  // follows missed ones: those before it are placed backward from it, newest first, until one
  // fails, and put first in `output->earlier_frames`. Forgets them all.
  void RetrackMissed(const Frame& from, Output* output);

  TrackingOptions options_;
  ViewGeometry geometry_;
  const Vocabulary* vocabulary_;
  double fps_;
  OrbExtractor extractor_;
  OrbExtractor init_extractor_;  // twice the features, for initialization (as ORB-SLAM)
  LossPolicy policy_;

  SubmapStore store_;
  std::unique_ptr<KeyframeBowWorker> keyframe_bow_;  // with options_.keyframe_worker
  Initializer initializer_;
  FramePlacer placer_;
  FeatureFlow flow_;           // its source: the last frame extracted and tracked, while frames follow it
  int followed_in_a_row_ = 0;  // frames tracked by flow since the source
  Relocalizer relocalizer_;

  int next_submap_number_;
  int submaps_closed_ = 0;
  int relocalizations_ = 0;
  bool lost_ = false;            // relocalize policy: the map is kept but the camera is not in it
  int frames_initializing_ = 0;  // frames since the last submap closed (submap policy)
  // Submap policy: the keyframes of the local map the camera was tracked in when it was lost
  // (the reference keyframe, its covisible keyframes and those holding the last frame's points).
  // While a new map initializes, a frame relocalized among them resumes that submap at once: the
  // camera is back where it was lost, as the relocalize baseline would continue. Anywhere else
  // in a closed submap is a loop, left to the merger (docs/tracking-loss.md).
  std::set<KeyframeId> lost_from_;
  // The frame the current submap started at, while it is one started after a loss that may still
  // give way to a closed submap (return_to_closed_frames); -1 otherwise.
  int young_submap_started_at_ = -1;
  // The saved map the current submap started in (invalid: none), the copies the submap holds of
  // its keyframes and points (saved -> copy), and the frame it was last followed at.
  SubmapId started_in_saved_;
  std::unordered_map<KeyframeId, KeyframeId> saved_keyframe_copies_;
  std::unordered_map<MapPointId, MapPointId> saved_point_copies_;
  int saved_followed_at_ = -1;
  TrackingState last_state_ = TrackingState::kNotTracked;

  std::optional<Frame> last_frame_;  // last tracked frame
  std::deque<Frame> missed_;         // frames since last_frame_ that found no pose, oldest first
  std::optional<Rigid3d> velocity_;  // cam_from_world(k) * world_from_cam(k - 1)
  double velocity_interval_s_ = 0;   // between frames k - 1 and k
  InverseDepthPlane last_depth_;     // of the last tracked frame's points, in its camera (rolling shutter)
  KeyframeId reference_keyframe_;
  int last_keyframe_frame_index_ = -1;
  int consecutive_failures_ = 0;
  double typical_sharpness_ = 0;  // running average over tracked frames

  // What the mapper has taken.
  void NoteKeyframeSent(KeyframeId id);
  struct SentKeyframe {
    KeyframeId id;
    bool answered = false;
    bool points_received = false;  // an update carried the mapper's points for it
  };
  std::deque<SentKeyframe> keyframes_sent_;  // the last ones, oldest first
  bool mapper_connected_ = true;
};

}  // namespace stitch
