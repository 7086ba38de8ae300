#pragma once
// Places a frame in a submap and confirms it against the local map. Methods, in this order, the
// first that the local map confirms wins:
//   1. motion model: the last frame's pose moved by the constant velocity, its points searched
//      by projection;
//   2. homography (options.homography_tracking): the last frame's tracked features matched by
//      descriptor, a RANSAC homography, its predictions searched, then PnP; also tried when the
//      motion model kept few of the last frame's points (the placement the local map supports
//      better stays);
//   3. reference keyframe: its points matched by bag of words (or a descriptor index), pose
//      optimized from the last frame's.
// Each stage is public for the relocalizer and for tests. One owner thread; not thread-safe
// (it keeps scratch buffers between frames).

#include <functional>
#include <optional>
#include <vector>

#include "stitch/features/descriptor_index.h"
#include "stitch/features/vocabulary.h"
#include "stitch/map/map.h"
#include "stitch/map/view_geometry.h"
#include "stitch/tracking/tracking_options.h"
#include "stitch/util/flat_id_set.h"

namespace stitch {

class FramePlacer {
 public:
  struct Placement {
    bool tracked = false;          // placed and confirmed by the local map
    bool placed = false;           // the last method tried found a pose (before the local map)
    bool pose_diverged = false;    // a pose optimization failed to converge on the way
    const char* tracked_by = "";   // "motion model", "homography" or "reference keyframe"
    double frame_to_frame_ms = 0;  // the methods: matching and pose
    double local_map_ms = 0;       // confirming against the local map
  };

  // `geometry` and `vocabulary` must outlive the placer. `wait_for_keyframe_bow` (optional) is
  // called when the reference keyframe's bag of words is still being computed elsewhere.
  FramePlacer(const TrackingOptions& options, const ViewGeometry* geometry, const Vocabulary* vocabulary,
              std::function<void()> wait_for_keyframe_bow = nullptr);

  // Places `frame` in `map` (methods above), given the last tracked frame of this map (or null)
  // and the velocity cam_from_world(k) * world_from_cam(k - 1) (or none). Backward (`last` a
  // later frame), the velocity is cam_from_world(k) * world_from_cam(k + 1). The local map must
  // confirm it with `min_inliers` points. `reference` (in: the reference keyframe, out: the
  // keyframe sharing most points with the placed frame) is kept when nothing is placed.
  Placement Place(Frame* frame, const Map& map, const Frame* last, const std::optional<Rigid3d>& velocity,
                  int min_inliers, KeyframeId* reference);

  // --- stages
  // The points tracked in `last` searched around their projection at `predicted`, then the pose
  // optimized; outliers dropped. Inliers kept (0: failed).
  int TrackWithMotionModel(const Map& map, Frame* frame, const Frame& last, const Rigid3d& predicted);
  // The last frame's tracked features followed through a homography; true when placed (never from a
  // `last` without descriptors: a frame followed by optical flow).
  bool TrackWithHomography(const Map& map, Frame* frame, const Frame& last);
  // The reference keyframe's points matched without a pose; the newest keyframe stands in for a
  // culled reference (and becomes `*reference`). Starts from `last`'s pose when given.
  bool TrackReferenceKeyframe(const Map& map, Frame* frame, const Frame* last, KeyframeId* reference);
  // Local map: the keyframes that observe the frame's points, their best covisible keyframes,
  // children and parents; their points predicted in view and not yet matched are searched by
  // projection, then the pose is optimized. True with at least `min_inliers` points. Sets
  // `*reference` to the keyframe sharing most points with the frame.
  bool TrackLocalMap(const Map& map, Frame* frame, int min_inliers, KeyframeId* reference);
  // Pose from the frame's 2D-3D matches: PnP RANSAC, then optimization; outliers dropped.
  bool PoseFromMatches(const Map& map, Frame* frame);
  // Pose-only optimization from the frame's current pose; marks (or with `discard_outliers`
  // drops) outliers. Inliers (0: too few observations or no convergence).
  int OptimizeFramePose(const Map& map, Frame* frame, bool discard_outliers);
  // An index over the frame's descriptors (built once per frame).
  const DescriptorIndex& FrameIndex(const Frame& frame);

 private:
  TrackingOptions options_;
  const ViewGeometry* geometry_;
  const Vocabulary* vocabulary_;
  std::function<void()> wait_for_keyframe_bow_;
  bool pose_diverged_ = false;
  std::vector<KeyframeId> local_keyframes_;     // TrackLocalMap's scratch
  FlatIdSet seen_points_;                       // ...kept to reuse its table
  std::optional<DescriptorIndex> frame_index_;  // of the frame being tracked
  int frame_index_of_ = -1;                     // ...its frame number
};

}  // namespace stitch
