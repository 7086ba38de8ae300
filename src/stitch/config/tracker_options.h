#pragma once
// Settings of the tracker service (the `tracker:` section of a stitch config).

#include <string>

#include "stitch/mosaic/keyframe_imagery.h"
#include "stitch/tracking/tracking_options.h"

namespace stitch {

struct TrackerOptions {
  int max_queued_frames = 2;            // realtime: frames waiting beyond this are dropped, oldest first
  std::string on_loss = "submap";       // submap: close the map and start a new one; relocalize: ORB-SLAM2-like
  bool wait_for_mapper = true;          // lockstep frames: after a keyframe, wait for the mapper's update first
  double mapper_timeout_s = 5.0;        // ...for at most this long; then track on without it and say so
  double mapper_busy_max_wait_s = 120;  // ...unless its heartbeat says it is running: then this long at most
  // Live frames: after a keyframe, while the last frame tracked fewer than live_wait_below_points
  // map points, wait at most this long for the points the mapper triangulates for it before the
  // next frame (once per keyframe; 0: never). A thin map (a young one, a fast turn) is what loses
  // track, and the keyframe's points are what thickens it; lockstep frames always wait.
  double live_wait_for_points_s = 0.05;
  int live_wait_below_points = 100;
  std::string state_file;                // keeps the next submap number across restarts ("" = none)
  KeyframeImageOptions keyframe_images;  // pictures for the ground's orthomosaic
  TrackingOptions tracking;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("max_queued_frames", max_queued_frames, "frames that may wait for the tracker; older ones are dropped");
    v("on_loss", on_loss, "after tracking loss: submap (stitch) or relocalize (ORB-SLAM2-like baseline)");
    v("wait_for_mapper", wait_for_mapper,
      "lockstep frames: after a keyframe, wait for the mapper before the next frame (reproducible runs; live frames "
      "never wait)");
    v("mapper_timeout_s", mapper_timeout_s,
      "longest wait for the mapper, seconds (lockstep: longest silence, its heartbeat included); then track on without "
      "it");
    v("mapper_busy_max_wait_s", mapper_busy_max_wait_s,
      "lockstep frames: longest wait for the mapper's answer to a keyframe while its heartbeat says it is running, "
      "seconds (at least mapper_timeout_s; a slow or starved machine: the run stays the same run)");
    v("live_wait_for_points_s", live_wait_for_points_s,
      "live frames: after a keyframe, while the last frame tracked fewer than live_wait_below_points map points, "
      "wait at most this long for the mapper's points for it before the next frame, seconds (once per keyframe; 0: "
      "never)");
    v("live_wait_below_points", live_wait_below_points,
      "live frames: the map points tracked below which the tracker waits for a keyframe's new points");
    v("state_file", state_file,
      "file keeping the next submap number, so submap ids stay unique across tracker restarts (empty: none)");
    v("keyframe_images", keyframe_images,
      "reduced pictures of keyframes for the ground's orthomosaic (<agent>/KEYFRAME_IMAGE), where the view moved on");
    v("tracking", tracking, "the tracking algorithm");
  }

  bool Check(std::string* why) const {
    auto fail = [&](const std::string& m) {
      if (why) *why = m;
      return false;
    };
    if (max_queued_frames < 1 || max_queued_frames > 1000)
      return fail("tracker.max_queued_frames must be in [1, 1000]");
    if (on_loss != "submap" && on_loss != "relocalize") return fail("tracker.on_loss must be submap or relocalize");
    if (!(mapper_timeout_s > 0)) return fail("tracker.mapper_timeout_s must be > 0");
    if (!(mapper_busy_max_wait_s > 0)) return fail("tracker.mapper_busy_max_wait_s must be > 0");
    if (!(live_wait_for_points_s >= 0 && live_wait_for_points_s <= 1))
      return fail("tracker.live_wait_for_points_s must be in [0, 1]");
    if (live_wait_below_points < 0) return fail("tracker.live_wait_below_points must be >= 0");
    return tracking.Check(why);
  }
};

}  // namespace stitch
