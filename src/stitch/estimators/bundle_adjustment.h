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

// Where a sensor outside the camera (the aircraft's GNSS receiver) put a point rigidly fixed to
// the camera (its antenna) at a moment between two keyframes: a prior on their poses. The
// antenna's place is interpolated linearly between where the two keyframes put it (at
// `antenna_in_camera` in each one's frame), `weight_after` of the way to `after`. Its residual is
// sqrt_information * (frame * antenna - position), `frame` a similarity between the map's frame
// and the priors' that the adjustment estimates with the map: squared, chi-square with 3 degrees
// of freedom for a right measurement. The priors tell the map its shape, what reprojections
// barely do: the slow drift of a monocular map's scale over a long flight (where the map lies,
// and its scale as a whole, stay the frame's).
struct PositionPrior {
  KeyframeId before, after;  // the same keyframe for a moment at one
  double weight_after = 0.0;
  Eigen::Vector3d antenna_in_camera = Eigen::Vector3d::Zero();  // in the map's units
  Eigen::Vector3d position = Eigen::Vector3d::Zero();           // in the map's frame
  Eigen::Matrix3d sqrt_information = Eigen::Matrix3d::Identity();
};
struct PositionPriors {
  std::vector<PositionPrior> priors;
  // A prior whose squared residual exceeds this (before the adjustment, or after its first pass)
  // is set aside: a fix that jumped. 14.16: what 99.7% of right ones stay within.
  double outlier_chi2 = 14.16;
};
// What the adjustment made of them.
struct PriorsReport {
  int used = 0;                           // in the adjustment
  int set_aside = 0;                      // outliers, before it or after its first pass
  double initial_rms = 0, final_rms = 0;  // of the used ones' residuals, per axis (1: as stated)
};

struct BundleAdjustmentReport {
  int keyframes_free = 0, keyframes_fixed = 0, points = 0, observations = 0;
  double initial_rms_px = 0, final_rms_px = 0;  // over all observations, before / after
  int outliers_removed = 0;
  PriorsReport priors;
  bool converged = false;
  bool interrupted = false;  // stopped early (`interrupted` said so): fewer iterations, no second pass
};

// Asked between iterations; true stops the adjustment with what it has reached (the mapper's
// next keyframe is waiting). Empty: never.
using Interruption = std::function<bool()>;

// Optimizes the poses of `free_keyframes` and every point they observe; other keyframes that
// observe those points, and any in `fixed_keyframes`, constrain the solution without moving.
// `priors` (may be null): position priors on keyframes in the adjustment (others are ignored),
// weighted as they say, Huber-robust, their outliers set aside.
BundleAdjustmentReport BundleAdjust(Map* map, const std::vector<KeyframeId>& free_keyframes,
                                    const std::vector<KeyframeId>& fixed_keyframes, const PinholeIntrinsics& intrinsics,
                                    const BundleAdjustmentOptions& options, const Interruption& interrupted = {},
                                    const PositionPriors* priors = nullptr);

// The window ORB-SLAM's local mapping optimizes: `keyframe` and its covisible keyframes (at most
// options.max_free_keyframes in all, the most covisible first) are free; keyframes seeing their
// points but outside the window are fixed.
BundleAdjustmentReport LocalBundleAdjustment(Map* map, KeyframeId keyframe, const PinholeIntrinsics& intrinsics,
                                             const BundleAdjustmentOptions& options,
                                             const Interruption& interrupted = {});

}  // namespace stitch
