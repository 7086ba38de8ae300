#include "stitch/estimators/bundle_adjustment.h"

#include <cmath>
#include <set>
#include <unordered_map>

#include <ceres/ceres.h>

#include "stitch/estimators/reprojection_error.h"

namespace stitch {
namespace {

struct ObservationRecord {
  KeyframeId keyframe;
  MapPointId point;
  int feature;
  ceres::ResidualBlockId residual;
};

// Stops the solver when the caller's interruption says so.
class InterruptionCallback : public ceres::IterationCallback {
 public:
  explicit InterruptionCallback(const Interruption& interrupted) : interrupted_(interrupted) {}
  ceres::CallbackReturnType operator()(const ceres::IterationSummary&) override {
    if (!interrupted_ || !interrupted_()) return ceres::SOLVER_CONTINUE;
    stopped_ = true;
    return ceres::SOLVER_TERMINATE_SUCCESSFULLY;
  }
  bool stopped() const { return stopped_; }

 private:
  const Interruption& interrupted_;
  bool stopped_ = false;
};

// Free keyframes from which the reduced camera system is solved sparsely: a local window's few
// cameras see each other's points, and a dense Schur complement is the fastest; a merged map's
// hundreds form a sparse system whose dense solve grows with the cube of their number (a
// 460-keyframe map: most of the merger's CPU).
constexpr int kSparseFromKeyframes = 64;

// `eliminated`: the blocks the Schur complement eliminates (the points); empty: Ceres chooses.
ceres::Solver::Summary Solve(ceres::Problem* problem, int iterations, int free_keyframes,
                             InterruptionCallback* callback, const std::vector<double*>& eliminated) {
  ceres::Solver::Options options;
  if (!eliminated.empty()) {
    auto ordering = std::make_shared<ceres::ParameterBlockOrdering>();
    for (double* block : eliminated) ordering->AddElementToGroup(block, 0);
    std::vector<double*> others;
    problem->GetParameterBlocks(&others);
    for (double* block : others) {
      if (!ordering->IsMember(block)) ordering->AddElementToGroup(block, 1);
    }
    options.linear_solver_ordering = ordering;
  }
  options.callbacks.push_back(callback);
  options.linear_solver_type = free_keyframes >= kSparseFromKeyframes ? ceres::SPARSE_SCHUR : ceres::DENSE_SCHUR;
  options.max_num_iterations = iterations;
  options.num_threads = 1;
  options.minimizer_progress_to_stdout = false;
  options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(options, problem, &summary);
  return summary;
}

// The residual of a position prior at one keyframe (one keyframe for both) or interpolated
// between two: sqrt_information * (frame * antenna - position). `frame` (the priors' frame against
// the map's, a similarity estimated with the map: a PoseParameters block and the logarithm of its
// scale) takes the antenna into the frame of the priors' positions; a pose (cam_from_world) puts
// the antenna in the world at q^-1 (a - t).
template <typename T>
Eigen::Matrix<T, 3, 1> AntennaInWorld(const T* pose, const Eigen::Vector3d& antenna_in_camera) {
  const Eigen::Quaternion<T> q(pose[3], pose[0], pose[1], pose[2]);
  const Eigen::Matrix<T, 3, 1> t(pose[4], pose[5], pose[6]);
  return q.conjugate() * (antenna_in_camera.cast<T>() - t);
}

template <typename T>
void PriorResidual(const PositionPrior& prior, const T* frame, const T* log_scale,
                   const Eigen::Matrix<T, 3, 1>& antenna, T* residual) {
  const Eigen::Quaternion<T> q(frame[3], frame[0], frame[1], frame[2]);
  const Eigen::Matrix<T, 3, 1> t(frame[4], frame[5], frame[6]);
  Eigen::Map<Eigen::Matrix<T, 3, 1>> r(residual);
  r = prior.sqrt_information.cast<T>() * (exp(log_scale[0]) * (q * antenna) + t - prior.position.cast<T>());
}

struct PriorAtOneKeyframe {
  const PositionPrior& prior;
  template <typename T>
  bool operator()(const T* frame, const T* log_scale, const T* pose, T* residual) const {
    PriorResidual<T>(prior, frame, log_scale, AntennaInWorld(pose, prior.antenna_in_camera), residual);
    return true;
  }
};

struct PriorBetweenKeyframes {
  const PositionPrior& prior;
  template <typename T>
  bool operator()(const T* frame, const T* log_scale, const T* before, const T* after, T* residual) const {
    const T w(prior.weight_after);
    PriorResidual<T>(prior, frame, log_scale,
                     (T(1.0) - w) * AntennaInWorld(before, prior.antenna_in_camera) +
                         w * AntennaInWorld(after, prior.antenna_in_camera),
                     residual);
    return true;
  }
};

// The prior's squared residual at the poses and frame given.
double PriorChi2(const PositionPrior& prior, const Sim3d& frame, const Rigid3d& before, const Rigid3d& after) {
  const auto antenna = [&](const Rigid3d& cam_from_world) {
    return cam_from_world.Inverse() * prior.antenna_in_camera;
  };
  const Eigen::Vector3d at = (1.0 - prior.weight_after) * antenna(before) + prior.weight_after * antenna(after);
  return (prior.sqrt_information * (frame * at - prior.position)).squaredNorm();
}

}  // namespace

std::pair<double, double> ObservationErrors(const Keyframe& keyframe, int feature, const Eigen::Vector3d& point,
                                            const PinholeIntrinsics& k, const ScalePyramid& pyramid) {
  const Eigen::Vector3d p = keyframe.cam_from_world * point;
  if (p.z() <= 0) return {1e18, 1e18};
  const double e2 = (keyframe.undistorted[feature] - k.Project(p)).squaredNorm();
  return {e2, e2 * pyramid.inverse_sigma2[keyframe.keypoints[feature].octave]};
}

bool BundleAdjustmentOptions::Check(std::string* why) const {
  if (iterations < 1 || refine_iterations < 0 || !(chi2_threshold > 0) || max_free_keyframes < 0) {
    if (why)
      *why = "bundle_adjustment: iterations >= 1, refine_iterations >= 0, chi2_threshold > 0, max_free_keyframes >= 0";
    return false;
  }
  return true;
}

BundleAdjustmentReport BundleAdjust(Map* map, const std::vector<KeyframeId>& free_keyframes,
                                    const std::vector<KeyframeId>& fixed_keyframes, const PinholeIntrinsics& k,
                                    const BundleAdjustmentOptions& options, const Interruption& interrupted,
                                    const PositionPriors* priors) {
  BundleAdjustmentReport report;
  const ScalePyramid& pyramid = map->pyramid();
  std::set<KeyframeId> free, fixed;
  for (KeyframeId id : free_keyframes) {
    if (map->FindKeyframe(id)) free.insert(id);
  }
  for (KeyframeId id : fixed_keyframes) {
    if (!free.count(id) && map->FindKeyframe(id)) fixed.insert(id);
  }
  // Points: all that the free keyframes observe. Keyframes: the free ones, and every other one
  // observing those points, fixed.
  std::set<MapPointId> point_ids;
  for (KeyframeId id : free) {
    for (MapPointId p : map->FindKeyframe(id)->points) {
      if (p.valid() && map->FindPoint(p)) point_ids.insert(p);
    }
  }
  for (MapPointId p : point_ids) {
    for (const auto& [kf, feature] : map->FindPoint(p)->observations) {
      if (!free.count(kf) && map->FindKeyframe(kf)) fixed.insert(kf);
    }
  }
  // Nothing fixed: hold the oldest free keyframe to remove the gauge freedom.
  if (fixed.empty() && !free.empty()) {
    fixed.insert(*free.begin());
    free.erase(free.begin());
  }
  report.keyframes_free = static_cast<int>(free.size());
  report.keyframes_fixed = static_cast<int>(fixed.size());
  report.points = static_cast<int>(point_ids.size());
  if (free.empty() || point_ids.empty()) return report;

  std::unordered_map<KeyframeId, PoseParameters> poses;
  for (const std::set<KeyframeId>* group : {&free, &fixed}) {
    for (KeyframeId id : *group) poses.emplace(id, PoseParameters(map->FindKeyframe(id)->cam_from_world));
  }
  std::unordered_map<MapPointId, Eigen::Vector3d> positions;
  for (MapPointId p : point_ids) positions[p] = map->FindPoint(p)->position;

  ceres::Problem problem;
  ceres::Manifold* pose_manifold = new PoseManifold;
  ceres::LossFunction* huber = new ceres::HuberLoss(std::sqrt(options.chi2_threshold));
  std::vector<ObservationRecord> records;
  double initial_sq = 0;
  for (MapPointId p : point_ids) {
    for (const auto& [kf, feature] : map->FindPoint(p)->observations) {
      const auto pose = poses.find(kf);
      if (pose == poses.end()) continue;
      const Keyframe* keyframe = map->FindKeyframe(kf);
      const double sqrt_information = std::sqrt(pyramid.inverse_sigma2[keyframe->keypoints[feature].octave]);
      ceres::CostFunction* cost =
          ReprojectionError::Create(keyframe->undistorted[feature], sqrt_information, k.fx, k.fy, k.cx, k.cy);
      const ceres::ResidualBlockId residual =
          problem.AddResidualBlock(cost, huber, pose->second.data(), positions[p].data());
      records.push_back({kf, p, feature, residual});
      initial_sq += std::min(1e6, ObservationErrors(*keyframe, feature, positions[p], k, pyramid).first);
    }
  }
  report.observations = static_cast<int>(records.size());
  report.initial_rms_px = std::sqrt(initial_sq / std::max<size_t>(1, records.size()));
  for (auto& [id, block] : poses) {
    // A keyframe none of whose points take part (all of them lost, or not yet received by a
    // replica) is not in the problem: it keeps its pose.
    if (!problem.HasParameterBlock(block.data())) continue;
    problem.SetManifold(block.data(), pose_manifold);
    if (fixed.count(id)) problem.SetParameterBlockConstant(block.data());
  }
  // Position priors on the keyframes in the problem, at least one of them free.
  struct PriorRecord {
    const PositionPrior* prior;
    ceres::ResidualBlockId residual;
  };
  std::vector<PriorRecord> prior_records;
  const auto in_problem = [&](KeyframeId id) {
    const auto pose = poses.find(id);
    return pose != poses.end() && problem.HasParameterBlock(pose->second.data());
  };
  // The priors' frame against the map's, a similarity estimated with it: where they place the map
  // (and its scale) comes from their own fit, as the map's error at its held keyframes is not to
  // bend it; what they tell the map is its shape (a long flight's drift).
  PoseParameters priors_frame{Rigid3d()};
  double priors_log_scale = 0.0;
  const auto frame_now = [&] {
    const Rigid3d rigid = priors_frame.ToRigid();
    return Sim3d(std::exp(priors_log_scale), rigid.rotation, rigid.translation);
  };
  const auto prior_chi2 = [&](const PositionPrior& prior) {
    return PriorChi2(prior, frame_now(), poses.at(prior.before).ToRigid(), poses.at(prior.after).ToRigid());
  };
  double prior_initial_sq = 0;
  if (priors) {
    ceres::LossFunction* prior_huber = new ceres::HuberLoss(std::sqrt(priors->outlier_chi2));
    bool loss_owned = false;
    for (const PositionPrior& prior : priors->priors) {
      if (!in_problem(prior.before) || !in_problem(prior.after) ||
          (fixed.count(prior.before) && fixed.count(prior.after)) || !(prior.weight_after >= 0.0) ||
          !(prior.weight_after <= 1.0)) {
        continue;
      }
      const double chi2 = prior_chi2(prior);
      if (!(chi2 <= priors->outlier_chi2)) {
        ++report.priors.set_aside;
        continue;
      }
      prior_initial_sq += chi2;
      const bool one = prior.before == prior.after;
      ceres::CostFunction* cost =
          one ? static_cast<ceres::CostFunction*>(
                    new ceres::AutoDiffCostFunction<PriorAtOneKeyframe, 3, 7, 1, 7>(new PriorAtOneKeyframe{prior}))
              : new ceres::AutoDiffCostFunction<PriorBetweenKeyframes, 3, 7, 1, 7, 7>(new PriorBetweenKeyframes{prior});
      const ceres::ResidualBlockId residual =
          one ? problem.AddResidualBlock(cost, prior_huber, priors_frame.data(), &priors_log_scale,
                                         poses.at(prior.before).data())
              : problem.AddResidualBlock(cost, prior_huber, priors_frame.data(), &priors_log_scale,
                                         poses.at(prior.before).data(), poses.at(prior.after).data());
      loss_owned = true;
      prior_records.push_back({&prior, residual});
    }
    if (loss_owned) {
      problem.SetManifold(priors_frame.data(), pose_manifold);
    } else {
      delete prior_huber;
    }
  }
  report.priors.used = static_cast<int>(prior_records.size());
  report.priors.initial_rms = std::sqrt(prior_initial_sq / (3.0 * std::max<size_t>(1, prior_records.size())));

  // With priors, the points are eliminated and every pose and the priors' frame kept (Ceres's own
  // choice would eliminate the frame too, whose rotation about a line of fixes is free).
  std::vector<double*> eliminated;
  if (!prior_records.empty()) {
    for (auto& [id, position] : positions) eliminated.push_back(position.data());
  }
  InterruptionCallback callback(interrupted);
  ceres::Solver::Summary summary = Solve(&problem, options.iterations, report.keyframes_free, &callback, eliminated);
  // Second pass without the observations that are outliers at the first pass's solution.
  const auto pose_of = [&](KeyframeId id) { return poses.at(id).ToRigid(); };
  const auto chi2_now = [&](const ObservationRecord& r) {
    const Keyframe* keyframe = map->FindKeyframe(r.keyframe);
    const Eigen::Vector3d p = pose_of(r.keyframe) * positions[r.point];
    if (p.z() <= 0) return 1e18;
    return (keyframe->undistorted[r.feature] - k.Project(p)).squaredNorm() *
           pyramid.inverse_sigma2[keyframe->keypoints[r.feature].octave];
  };
  if (options.refine_iterations > 0 && !callback.stopped()) {
    for (const auto& r : records) {
      if (chi2_now(r) > options.chi2_threshold) problem.RemoveResidualBlock(r.residual);
    }
    for (auto r = prior_records.begin(); r != prior_records.end();) {
      if (prior_chi2(*r->prior) <= priors->outlier_chi2) {
        ++r;
        continue;
      }
      problem.RemoveResidualBlock(r->residual);
      ++report.priors.set_aside;
      r = prior_records.erase(r);
    }
    report.priors.used = static_cast<int>(prior_records.size());
    summary = Solve(&problem, options.refine_iterations, report.keyframes_free, &callback, eliminated);
  }
  report.interrupted = callback.stopped();
  report.converged = summary.IsSolutionUsable();
  if (!report.converged) return report;

  // Write back, then drop the observations that are still outliers.
  for (KeyframeId id : free) map->FindKeyframe(id)->cam_from_world = pose_of(id);
  for (MapPointId p : point_ids) {
    if (MapPoint* point = map->FindPoint(p)) point->position = positions[p];
  }
  double final_sq = 0;
  int counted = 0;
  for (const auto& r : records) {
    const Keyframe* keyframe = map->FindKeyframe(r.keyframe);
    const MapPoint* point = map->FindPoint(r.point);
    if (!keyframe || !point || keyframe->points[r.feature] != r.point) continue;
    const auto [e2, chi2] = ObservationErrors(*keyframe, r.feature, point->position, k, pyramid);
    if (options.remove_outliers && chi2 > options.chi2_threshold) {
      map->EraseObservation(r.keyframe, r.point);
      ++report.outliers_removed;
      continue;
    }
    final_sq += e2;
    ++counted;
  }
  report.final_rms_px = std::sqrt(final_sq / std::max(1, counted));
  double prior_final_sq = 0;
  for (const PriorRecord& r : prior_records) prior_final_sq += prior_chi2(*r.prior);
  report.priors.final_rms = std::sqrt(prior_final_sq / (3.0 * std::max<size_t>(1, prior_records.size())));
  for (MapPointId p : point_ids) map->UpdatePointGeometry(p);
  return report;
}

BundleAdjustmentReport LocalBundleAdjustment(Map* map, KeyframeId keyframe, const PinholeIntrinsics& k,
                                             const BundleAdjustmentOptions& options, const Interruption& interrupted) {
  std::vector<KeyframeId> window{keyframe};
  if (const Keyframe* kf = map->FindKeyframe(keyframe)) {
    for (const auto& [weight, other] : kf->ordered) {
      if (options.max_free_keyframes > 0 && static_cast<int>(window.size()) >= options.max_free_keyframes) break;
      window.push_back(other);
    }
  }
  return BundleAdjust(map, window, {}, k, options, interrupted);
}

}  // namespace stitch
