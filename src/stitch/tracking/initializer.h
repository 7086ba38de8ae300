#pragma once
// Monocular map initialization, as ORB-SLAM2: the first usable frame becomes the reference; each
// later one is matched to it (each feature searched near where it was last seen), and when
// enough matches agree with a homography or an essential matrix (scored side by side,
// two_view.h) the two frames become keyframes 0 and 1 of a new submap, with the triangulated
// points (less those the frames in between see elsewhere: look-alikes matched along their
// epipolar lines), bundle adjusted and scaled to unit median depth. A reference without enough matches
// is replaced by the current frame, unless the camera moves toward the scene (its features grew
// out of level 0: then they are matched across levels and the essential matrix is waited for);
// a camera that does not move never initializes (no parallax). One owner thread; not
// thread-safe.

#include <memory>
#include <string>

#include "stitch/features/vocabulary.h"
#include "stitch/map/map.h"
#include "stitch/map/view_geometry.h"
#include "stitch/tracking/tracking_options.h"
#include "stitch/tracking/tracking_result.h"

namespace stitch {

class Initializer {
 public:
  struct Result {
    // Without a map: why not yet (kTooFewFeatures, kTooFewMatches or kInitFailed) and the detail.
    TrackingReason reason = TrackingReason::kInitFailed;
    std::string detail;
    // The initial map: keyframes 0 (the reference) and 1 (this frame) and their points, and this
    // frame placed in it (pose, points, no outliers).
    std::unique_ptr<Map> map;
    Frame frame;
    // The frames it started from, placed in the initial map once it exists: the reference
    // (keyframe 0) and each frame since that matched it (posed from those matches, kept where at
    // least min_inliers agree), in frame order. Without them the frames a new map waited through
    // for parallax would be in no map.
    struct PlacedFrame {
      int frame_index = -1;
      int64_t t_ns = 0;
      Rigid3d cam_from_world;  // in the initial map
      int num_features = 0;
      int tracked_points = 0;  // agreeing with the pose
      bool is_reference = false;
    };
    std::vector<PlacedFrame> earlier;
  };

  // `geometry` and `vocabulary` must outlive the initializer.
  Initializer(const TrackingOptions& options, const ViewGeometry* geometry, const Vocabulary* vocabulary);

  // Takes the next frame (extracted with twice the tracker's features, as ORB-SLAM); a map with
  // id `submap` when it initializes.
  Result Add(Frame frame, SubmapId submap);
  // Forgets the reference frame.
  void Reset();
  bool has_reference() const { return reference_.has_value(); }

 private:
  // The map from the reference and `frame` given their matches and two-view geometry; null with
  // `why` when the bundle-adjusted map is too thin.
  std::unique_ptr<Map> BuildMap(Frame* frame, const std::vector<int>& matches, const TwoViewResult& two_view,
                                SubmapId submap, std::string* why);

  // The log's line for an initialization: the model and its share of the score, points, parallax,
  // and the attempts refused with this reference.
  std::string DescribeInitialization(const TwoViewResult& two_view, int frames_since_reference) const;

  TrackingOptions options_;
  const ViewGeometry* geometry_;
  const Vocabulary* vocabulary_;
  // Places the reference and the frames in between_ in the initial map (reference keyframe 0,
  // `frame` keyframe 1).
  std::vector<Result::PlacedFrame> PlaceEarlierFrames(const Map& map, const Frame& reference, const Frame& frame) const;
  // Removes the points that the frames it waited through (`placed`) see elsewhere than they
  // project: a feature matched to the wrong one along its epipolar line; returns how many.
  int CullPointsTheEarlierFramesDisagreeWith(Map* map, const std::vector<Result::PlacedFrame>& placed) const;

  std::optional<Frame> reference_;
  std::vector<Eigen::Vector2d> previous_;  // where each reference feature was last matched
  // Matches `frame` with the reference: level 0 alone, or across levels once the camera is found
  // to move toward the scene (TrackingOptions::init_across_levels). Returns the count.
  int MatchReference(const Frame& frame, std::vector<int>* matches);
  static constexpr double kMatchRatio = 0.9;
  static constexpr int kMaxLevel = 7;
  // Of the matches across levels, the share that must have grown a level to keep the reference.
  static constexpr double kGrownFraction = 0.4;
  int culled_ = 0;              // points of the last initial map that the frames it waited through disagreed with
  bool across_levels_ = false;  // the reference is matched across levels (the camera moves toward the scene)
  // Attempts with this reference that two-view geometry or the initial map refused, and why the
  // last one was: an initialization says what it waited through.
  int refused_ = 0;
  std::string last_refusal_;
  // Frames since the reference that matched it but did not initialize: only what places them,
  // each match's reference feature and where the frame saw it; at most kMaxBetween, the newest.
  struct Between {
    int frame_index = -1;
    int64_t t_ns = 0;
    int num_features = 0;
    std::vector<int> reference_features;
    std::vector<Eigen::Vector2d> pixels;  // undistorted
    std::vector<double> inverse_sigma2;   // of the level each was seen at
  };
  static constexpr size_t kMaxBetween = 60;
  std::vector<Between> between_;
};

}  // namespace stitch
