#pragma once
// Settings of the tracking algorithm (the `tracker.tracking:` section of a stitch config) and the
// loss policy. A light header: the configuration includes it without the tracker's code.

#include <string>

#include "stitch/estimators/two_view.h"
#include "stitch/features/orb_extractor.h"

namespace stitch {

// Frames between keyframes followed by optical flow (feature_flow.h).
struct FeatureFlowOptions {
  // Off by default: it takes 15-33% of the CPU off a frame and costs accuracy (fewer keyframes,
  // poses without the local map's search; docs/speed.md has the gate's figures).
  bool enabled = false;  // follow features between keyframes (false: every frame extracted)
  int max_frames = 4;    // frames followed in a row before one is extracted again
  int window_px = 21;    // Lucas-Kanade window, pixels (odd)
  int levels = 3;        // pyramid levels above the image (each half the size)
  // A followed position whose flow error (mean absolute difference over the window, grey levels)
  // is above this is dropped.
  double max_error = 20.0;
  // A followed frame is kept only with this share of the reference keyframe's points above the
  // share below which a keyframe is made: flow keeps points that an extracted frame's matching
  // may lose, so at the threshold itself an extracted frame might have become a keyframe.
  double keyframe_margin = 0.05;
  // Frames are followed only while the motion model turns the camera by at most this many degrees
  // a frame: Lucas-Kanade shifts its window but does not turn or warp it (a conservative limit,
  // not shown to help on TUM fr1/rpy: docs/speed.md).
  double max_turn_deg = 1.0;
  // A point is followed only while the predicted pose changes its depth by at most this share of
  // its depth in the source frame (its patch's scale; 0: no limit): a camera moving towards the
  // ground it sees (forward, oblique) enlarges its near patches.
  double max_scale_change = 0.05;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("enabled", enabled, "follow the map points into frames between keyframes by optical flow, extracting less");
    v("max_frames", max_frames, "frames followed in a row before one is extracted again");
    v("window_px", window_px, "Lucas-Kanade window, pixels (odd)");
    v("levels", levels, "Lucas-Kanade pyramid levels above the image");
    v("max_error", max_error, "largest flow error kept (mean absolute grey-level difference over the window)");
    v("max_turn_deg", max_turn_deg,
      "frames are followed only while the camera turns at most this many degrees a frame");
    v("max_scale_change", max_scale_change,
      "a point is followed only while its depth changes by at most this share of the source frame's (0: no limit)");
    v("keyframe_margin", keyframe_margin,
      "a followed frame is kept only with this share of the reference keyframe's points above the keyframe ratio");
  }
  bool Check(std::string* why) const;
};

struct TrackingOptions {
  OrbOptions orb;
  FeatureFlowOptions flow;  // frames between keyframes followed by optical flow (feature_flow.h)
  TwoViewOptions initialization;
  int init_min_features = 100;  // a frame needs this many features to take part in initialization
  int init_min_matches = 50;    // matches with the reference frame to keep it and attempt initialization
  int init_window_px = 100;     // search window around each feature's last match
  // Where too few level-0 features match the reference and most of those matched across pyramid
  // levels grew (the camera moves toward the scene: a car, a forward-looking aircraft), the
  // reference is kept and matched across levels, and the map waits for an essential matrix. Off
  // by default: the car's maps begin sooner and again after a loss, but less accurate
  // (docs/architecture.md).
  bool init_across_levels = false;
  int min_inliers = 30;                // tracked points for a frame to count as tracked
  int min_inliers_after_failure = 30;  // ...right after an untracked frame (as ORB-SLAM after relocalization)
  int lost_after_frames = 3;           // consecutive untracked frames that make tracking lost
  // A frame that neither the motion model nor the reference keyframe places is relocalized in
  // the whole current submap (bag of words, then PnP) before it counts as untracked: a fast turn
  // of a handheld camera, not a loss (ORB-SLAM3's "recently lost" state).
  bool relocalize_untracked = true;
  double keyframe_ratio = 0.9;  // new keyframe when the frame tracks fewer than this x reference's points
  // ...or this x while the camera moves along its viewing direction (its displacement since the
  // reference keyframe within keyframe_along_axis_max_angle_deg of its optical axis): a forward
  // camera, whose points leave the view at every edge and grow as it nears them, holds a thin
  // local map and drifts in scale at 0.9; a downward or oblique survey camera is not affected.
  // docs/benchmarks.md "Keyframes for a forward camera".
  double keyframe_ratio_along_axis = 0.95;
  double keyframe_along_axis_max_angle_deg = 25.0;
  int max_keyframe_gap = 0;  // frames between keyframes at most (0: one second of frames)
  // Below this median parallax with the reference keyframe (degrees: a camera that mostly
  // rotates), a frame becomes a keyframe only when keyframe_gap_without_parallax_s has passed
  // since the last one or it tracks fewer than keyframe_ratio_without_parallax of the
  // reference's points (0: off). docs/benchmarks.md "Keyframes without parallax".
  double keyframe_min_parallax_deg = 1.0;
  double keyframe_ratio_without_parallax = 0.5;
  // Of the sequence's time (0: only the ratio). The tracker service does not know its source's
  // rate and counts it in frames at 30 fps (6 frames; docs/benchmarks.md "A street for the car").
  double keyframe_gap_without_parallax_s = 0.2;
  // A frame that tracks map points in fewer than this share of its feature-holding image cells
  // (8x6) becomes a keyframe whatever the ratio (new ground in view; 0: off). Off by default: it
  // helps the forward camera and costs the oblique ones (docs/benchmarks.md).
  double keyframe_min_coverage = 0.0;
  double keyframe_coverage_min_parallax_deg = 2.0;  // ...when its median parallax with the reference is at least this
  // A new keyframe is made while fewer than this many sent ones wait for the mapper (1: only
  // when it has caught up). In lockstep the tracker waits for the mapper, so this matters to
  // live frames: a keyframe sent while the mapper adjusts the last one cuts that adjustment short.
  int keyframes_in_flight = 2;
  // Frames sharper than this x the recent tracked frames are tracked; others are blurred.
  double min_relative_sharpness = 0.45;
  // The camera's readout delay from one image row to the next, microseconds (0: a global
  // shutter): each frame's features are moved to where its first row's instant saw them, by the
  // motion model (rolling_shutter.h). -1: the source's (`stitch run` resolves it: the synthetic
  // flight's, a calibration's Camera.line_delay_us, else 0).
  double rolling_shutter_line_us = -1;
  int relocalization_candidates = 8;  // keyframes tried per frame when relocalizing
  // Submap policy: frames a new map tries to initialize before closed submaps are tried.
  int relocalize_closed_after_frames = 20;
  // Submap policy: while a new map initializes, frames are relocalized at once into the local map
  // the camera was lost from (its keyframes only); where one lands with at most
  // resume_max_parallax_deg of median parallax at the keyframe it lands at (the camera is back
  // where it was lost, not moved on to new ground), the camera goes on in that submap, as the
  // relocalize baseline would after a blackout (docs/tracking-loss.md).
  bool resume_where_lost = true;
  double resume_max_parallax_deg = 5.0;
  // Once a map initializes, the frames it waited through for parallax (the reference and those
  // since that matched it) are placed in it too, from their matches with the reference.
  bool place_initialization_frames = true;
  // Submap policy: for this many frames after a new submap starts (following a loss), every
  // return_to_closed_every-th frame is also relocalized into the closed submaps; where it lands,
  // the young submap closes and the camera goes on in the closed one, as the relocalize baseline
  // would have (0: never). Off by default: it wins on handheld video and loses on the survey
  // (docs/tracking-loss.md has the figures' command).
  int return_to_closed_frames = 0;
  int return_to_closed_every = 2;
  int relocalization_min_inliers = 50;  // tracked points that accept a relocalized pose
  // Frames that found no pose (skipped, lost, waiting for a new map) are kept, at most this many,
  // and once a later frame is placed again they are placed backward from it, newest first, each
  // from the one after it and confirmed by relocalization_min_inliers local-map points (a pose
  // from a weaker prediction, as a relocalized one), until one fails (0: off). A frame missed on
  // the way into a fast turn is often placed from the way out.
  int retrack_missed_frames = 20;
  // Memory over a long flight (submap policy): a submap that reaches submap_max_keyframes hands
  // over to a new one that starts with copies of the local map (the reference keyframe and its
  // handover_keyframes - 1 best covisible ones, their points, the same poses), so tracking goes
  // on without a break and the merger joins the two on the copies (0: no cap). Closed submaps
  // are dropped from the tracker, oldest first, while they hold more than closed_keyframes_held
  // keyframes (after a loss the one just closed is kept: the camera may resume it); the tracker
  // relocalizes only into those it holds. The mapper lets a dropped submap go once the merger
  // holds it whole.
  int submap_max_keyframes = 300;
  int handover_keyframes = 10;
  int closed_keyframes_held = 200;
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
  // A saved map (stitch run --map; map_file.h) the camera relocalizes in while a new map
  // initializes; empty: none.
  std::string prior_map;
  // With prior_map: track in the saved map only, without mapping (no keyframe, no submap of its
  // own): a lost camera relocalizes in it again (stitch run --localize-only).
  bool localize_only = false;
  // A submap started in the saved map copies in the saved keyframes around the camera every
  // this many frames as it moves on (0: only the copies it started with).
  int saved_map_follow_frames = 5;
  int agent_number = 0;  // high bits of every id this tracker makes
  int first_submap_number = 1;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("orb", orb, "feature extraction");
    v("flow", flow, "frames between keyframes: the map points followed by optical flow instead of extracted");
    v("initialization", initialization, "two-view map initialization");
    v("init_min_features", init_min_features, "features a frame needs to take part in initialization");
    v("init_min_matches", init_min_matches, "matches with the reference frame needed to attempt initialization");
    v("init_window_px", init_window_px, "initialization search window, pixels");
    v("init_across_levels", init_across_levels,
      "where too few level-0 features match the reference and most matches across pyramid levels grew (the camera "
      "moves toward the scene), keep the reference, match it across levels and wait for an essential matrix");
    v("min_inliers", min_inliers, "tracked points for a frame to count as tracked");
    v("min_inliers_after_failure", min_inliers_after_failure, "tracked points needed right after an untracked frame");
    v("lost_after_frames", lost_after_frames,
      "consecutive untracked frames that make tracking lost (one bad frame is skipped)");
    v("relocalize_untracked", relocalize_untracked,
      "a frame the motion model and the reference keyframe cannot place is relocalized in the whole current submap "
      "before it counts as untracked");
    v("keyframe_ratio", keyframe_ratio,
      "new keyframe when tracking fewer than this fraction of the reference keyframe's points");
    v("keyframe_ratio_along_axis", keyframe_ratio_along_axis,
      "the keyframe ratio while the camera moves along its viewing direction (a forward camera)");
    v("keyframe_along_axis_max_angle_deg", keyframe_along_axis_max_angle_deg,
      "the camera moves along its viewing direction when its displacement since the reference keyframe is within "
      "this angle of its optical axis, degrees");
    v("max_keyframe_gap", max_keyframe_gap, "frames between keyframes at most (0: one second)");
    v("keyframe_min_parallax_deg", keyframe_min_parallax_deg,
      "below this median parallax with the reference keyframe, degrees, a keyframe needs "
      "keyframe_gap_without_parallax_s since the last one or keyframe_ratio_without_parallax (0: off)");
    v("keyframe_ratio_without_parallax", keyframe_ratio_without_parallax,
      "a frame with little parallax becomes a keyframe at once when tracking fewer than this fraction of the "
      "reference's points");
    v("keyframe_gap_without_parallax_s", keyframe_gap_without_parallax_s,
      "a frame with little parallax becomes a keyframe only this long after the last one, seconds of the sequence "
      "(unless keyframe_ratio_without_parallax; 0: only the ratio)");
    v("keyframe_min_coverage", keyframe_min_coverage,
      "a frame that tracks map points in fewer than this share of its feature-holding image cells (8x6 grid) becomes "
      "a keyframe (new ground in view; 0: off)");
    v("keyframe_coverage_min_parallax_deg", keyframe_coverage_min_parallax_deg,
      "a keyframe for new ground needs at least this median parallax with the reference keyframe, degrees (a turning "
      "camera cannot triangulate what it sees newly)");
    v("keyframes_in_flight", keyframes_in_flight,
      "a keyframe is made while fewer than this many sent ones wait for the mapper (1: only when it caught up)");
    v("min_relative_sharpness", min_relative_sharpness,
      "a frame less sharp than this fraction of recent tracked frames is skipped as motion-blurred (0: off)");
    v("rolling_shutter_line_us", rolling_shutter_line_us,
      "the camera's readout delay from one image row to the next, microseconds: each frame's features are moved to "
      "where its first row's instant saw them, by the motion model (0: a global shutter; -1: the source's, the "
      "synthetic flight's synthetic.camera.rolling_shutter_line_us or a calibration's Camera.line_delay_us, else 0)");
    v("relocalize_closed_after_frames", relocalize_closed_after_frames,
      "submap policy: frames a new map tries to initialize alone before relocalization into closed submaps is tried "
      "too");
    v("resume_where_lost", resume_where_lost,
      "submap policy: while a new map initializes, relocalize each frame at once into the local map the camera was "
      "lost from; where one lands without moving on (resume_max_parallax_deg), that submap goes on");
    v("resume_max_parallax_deg", resume_max_parallax_deg,
      "resuming where lost: the most median parallax, degrees, between the frame and the keyframe it relocalized at "
      "(more: the camera moved on to new ground, which a new submap maps better)");
    v("place_initialization_frames", place_initialization_frames,
      "once a map initializes, place the frames it waited through for parallax in it too (the reference frame and "
      "those since that matched it)");
    v("return_to_closed_frames", return_to_closed_frames,
      "submap policy: for this many frames after a new submap starts, frames are also relocalized into the closed "
      "submaps; where one lands, the young submap closes and the camera goes on in the closed one (0: never)");
    v("return_to_closed_every", return_to_closed_every,
      "submap policy: every this-many-th frame of that window is tried (the others cost nothing)");
    v("relocalization_candidates", relocalization_candidates,
      "keyframes (by bag of words) tried per frame when relocalizing");
    v("relocalization_min_inliers", relocalization_min_inliers, "tracked points needed to accept a relocalized pose");
    v("retrack_missed_frames", retrack_missed_frames,
      "frames that found no pose are kept (at most this many) and placed backward from the next frame placed, "
      "newest first, each confirmed by relocalization_min_inliers points, until one fails (0: off)");
    v("submap_max_keyframes", submap_max_keyframes,
      "submap policy: a submap holding this many keyframes hands over to a new one that starts with copies of the "
      "local map, so memory stays bounded over a long flight (0: no cap)");
    v("handover_keyframes", handover_keyframes,
      "keyframes copied into the new submap at a handover (the reference keyframe and its best covisible ones)");
    v("closed_keyframes_held", closed_keyframes_held,
      "closed submaps are dropped from the tracker, oldest first, while they hold more keyframes than this (after a "
      "loss the one just closed is kept; the mapper keeps a dropped one until the merger holds it whole)");
    v("reference_matching", reference_matching,
      "matching against the reference keyframe and relocalization candidates: bow (vocabulary direct index), lsh or "
      "brute_force");
    v("homography_tracking", homography_tracking,
      "when the motion model fails, track through a homography fitted to matches with the last frame (fast rotation, "
      "jitter)");
    v("homography_threshold_px", homography_threshold_px, "RANSAC inlier threshold of that homography, pixels");
    v("homography_search_px", homography_search_px,
      "search radius around the homography's predicted positions, pixels at level 0");
    v("homography_roi_per_cell", homography_roi_per_cell,
      "homography matching only from feature-rich cells of the last frame (8x6), at most this many strongest features "
      "each (0: all tracked features)");
    v("keyframe_worker", keyframe_worker,
      "compute new keyframes' bag of words (relocalization database) on a background thread, off the frame loop");
    v("agent_number", agent_number, "number of this aircraft in every id (0-32766)");
    v("prior_map", prior_map,
      "a saved map (.stitchmap) the camera relocalizes in from the first frame and after every loss; where it "
      "lands, a new submap starts from copies of the saved map's local map (stitch run --map; empty: none)");
    v("localize_only", localize_only,
      "with prior_map: track in the saved map only, making no keyframe and no submap of this flight; a lost camera "
      "relocalizes in it again (stitch run --localize-only)");
    v("saved_map_follow_frames", saved_map_follow_frames,
      "a submap started in the saved map copies in the saved keyframes around the camera every this many frames as "
      "it moves on (0: only the copies it started from)");
    v("first_submap_number", first_submap_number, "number of the first submap (1-65535)");
  }
  bool Check(std::string* why) const;
};

// What the tracker does when tracking is lost.
enum class LossPolicy {
  kNewSubmap,   // close the submap, start a new one at once (stitch)
  kRelocalize,  // keep the map, discard frames until relocalized (ORB-SLAM2, the baseline)
};
// "submap" or "relocalize"; throws stitch::Error for anything else.
LossPolicy ParseLossPolicy(const std::string& name);

}  // namespace stitch
