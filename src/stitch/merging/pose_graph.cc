#include "stitch/merging/pose_graph.h"

#include <cmath>

#include <ceres/ceres.h>

namespace stitch {
namespace {

struct Parameters {
  double rotation[4];  // x y z w (Eigen order)
  double translation[3];
  double log_scale;
};

struct RelativeSim3Error {
  RelativeSim3Error(const Sim3d& i_from_j, double weight) : measured(i_from_j), weight(weight) {}

  template <class T>
  bool operator()(const T* qi, const T* ti, const T* si, const T* qj, const T* tj, const T* sj, T* residual) const {
    const Eigen::Map<const Eigen::Quaternion<T>> rotation_i(qi), rotation_j(qj);
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> translation_i(ti), translation_j(tj);
    // Predicted i_from_j = (world_from_i)^-1 * world_from_j.
    const Eigen::Quaternion<T> rotation = rotation_i.conjugate() * rotation_j;
    const Eigen::Matrix<T, 3, 1> translation =
        (rotation_i.conjugate() * (translation_j - translation_i)) * ceres::exp(-si[0]);
    const T log_scale = sj[0] - si[0];
    Eigen::Quaternion<T> error = measured.rotation.cast<T>().conjugate() * rotation;
    const T sign = error.w() < T(0) ? T(-1) : T(1);
    residual[0] = T(weight) * T(2) * sign * error.x();
    residual[1] = T(weight) * T(2) * sign * error.y();
    residual[2] = T(weight) * T(2) * sign * error.z();
    const Eigen::Matrix<T, 3, 1> translation_error = translation - measured.translation.cast<T>();
    residual[3] = T(weight) * translation_error.x();
    residual[4] = T(weight) * translation_error.y();
    residual[5] = T(weight) * translation_error.z();
    residual[6] = T(weight) * (log_scale - T(std::log(measured.scale)));
    return true;
  }

  Sim3d measured;
  double weight;
};

}  // namespace

PoseGraphReport OptimizePoseGraph(std::map<KeyframeId, Sim3d>* poses, const std::vector<PoseGraphEdge>& edges,
                                  const std::vector<KeyframeId>& fixed, int iterations) {
  PoseGraphReport report;
  std::map<KeyframeId, Parameters> parameters;
  for (const auto& [id, pose] : *poses) {
    Parameters p;
    p.rotation[0] = pose.rotation.x();
    p.rotation[1] = pose.rotation.y();
    p.rotation[2] = pose.rotation.z();
    p.rotation[3] = pose.rotation.w();
    for (int k = 0; k < 3; ++k) p.translation[k] = pose.translation[k];
    p.log_scale = std::log(pose.scale);
    parameters[id] = p;
  }
  ceres::Problem problem;
  ceres::Manifold* quaternion = new ceres::EigenQuaternionManifold;
  for (const PoseGraphEdge& e : edges) {
    auto i = parameters.find(e.i), j = parameters.find(e.j);
    if (i == parameters.end() || j == parameters.end() || e.i == e.j) continue;
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<RelativeSim3Error, 7, 4, 3, 1, 4, 3, 1>(
                                 new RelativeSim3Error(e.i_from_j, e.weight)),
                             e.robust ? new ceres::HuberLoss(e.weight) : nullptr, i->second.rotation,
                             i->second.translation, &i->second.log_scale, j->second.rotation, j->second.translation,
                             &j->second.log_scale);
    ++report.edges;
  }
  for (auto& [id, p] : parameters) {
    if (!problem.HasParameterBlock(p.rotation)) continue;
    problem.SetManifold(p.rotation, quaternion);
    ++report.nodes;
  }
  if (report.edges == 0) {
    delete quaternion;
    return report;
  }
  for (KeyframeId id : fixed) {
    auto p = parameters.find(id);
    if (p == parameters.end() || !problem.HasParameterBlock(p->second.rotation)) continue;
    problem.SetParameterBlockConstant(p->second.rotation);
    problem.SetParameterBlockConstant(p->second.translation);
    problem.SetParameterBlockConstant(&p->second.log_scale);
  }
  ceres::Solver::Options options;
  options.max_num_iterations = iterations;
  options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  report.initial_cost = summary.initial_cost;
  report.final_cost = summary.final_cost;
  report.converged =
      summary.termination_type == ceres::CONVERGENCE || summary.termination_type == ceres::NO_CONVERGENCE;
  for (auto& [id, p] : parameters) {
    if (!problem.HasParameterBlock(p.rotation)) continue;
    (*poses)[id] = Sim3d(std::exp(p.log_scale),
                         Eigen::Quaterniond(p.rotation[3], p.rotation[0], p.rotation[1], p.rotation[2]).normalized(),
                         Eigen::Vector3d(p.translation[0], p.translation[1], p.translation[2]));
  }
  return report;
}

}  // namespace stitch
