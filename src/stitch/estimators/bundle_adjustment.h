#pragma once
// Bundle adjustment with Ceres: keyframe poses and map point positions that minimize the
// reprojection error of every observation (Huber cost, each residual weighted by its pyramid
// level), with chosen keyframes held fixed. Used for the local window (mapper) and for the whole
// initial map.

#include <functional>
#include <utility>
#include <vector>

#include "stitch/map/map.h"

namespace stitch {

struct BundleAdjustmentOptions {
  int iterations = 5;             // first pass, with the Huber cost
  int refine_iterations = 10;     // second pass, after removing outliers
  double chi2_threshold = 5.991;  // observations above this (normalized, 2 DoF) are outliers
  bool remove_outliers = true;    // erase outlier observations from the map after the passes
  // Local window only: keyframes free to move, the new one and its best covisible ones (0: every
  // covisible keyframe, as ORB-SLAM). The others that see their points are held fixed.
  int max_free_keyframes = 0;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("iterations", iterations, "iterations of the first (robust) pass");
    v("refine_iterations", refine_iterations, "iterations after setting outliers aside");
    v("chi2_threshold", chi2_threshold, "normalized squared reprojection error that makes an outlier");
    v("max_free_keyframes", max_free_keyframes,
      "local window: keyframes free to move, the new one and its most covisible (0: all covisible ones)");
  }
  bool Check(std::string* why) const;
};

// The squared reprojection error in pixels of `keyframe`'s `feature` as an observation of `point`,
// and its normalized (chi-square) form; 1e18 behind the camera.
std::pair<double, double> ObservationErrors(const Keyframe& keyframe, int feature, const Eigen::Vector3d& point,
                                            const PinholeIntrinsics& k, const ScalePyramid& pyramid);

struct BundleAdjustmentReport {
  int keyframes_free = 0, keyframes_fixed = 0, points = 0, observations = 0;
  double initial_rms_px = 0, final_rms_px = 0;  // over all observations, before / after
  int outliers_removed = 0;
  bool converged = false;
  bool interrupted = false;  // stopped early (`interrupted` said so): fewer iterations, no second pass
};

// Asked between iterations; true stops the adjustment with what it has reached (the mapper's
// next keyframe is waiting). Empty: never.
using Interruption = std::function<bool()>;

// Optimizes the poses of `free_keyframes` and every point they observe; other keyframes that
// observe those points, and any in `fixed_keyframes`, constrain the solution without moving.
BundleAdjustmentReport BundleAdjust(Map* map, const std::vector<KeyframeId>& free_keyframes,
                                    const std::vector<KeyframeId>& fixed_keyframes, const PinholeIntrinsics& intrinsics,
                                    const BundleAdjustmentOptions& options, const Interruption& interrupted = {});

// The window ORB-SLAM's local mapping optimizes: `keyframe` and its covisible keyframes (at most
// options.max_free_keyframes in all, the most covisible first) are free; keyframes seeing their
// points but outside the window are fixed.
BundleAdjustmentReport LocalBundleAdjustment(Map* map, KeyframeId keyframe, const PinholeIntrinsics& intrinsics,
                                             const BundleAdjustmentOptions& options,
                                             const Interruption& interrupted = {});

}  // namespace stitch
