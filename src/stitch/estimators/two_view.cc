#include "stitch/estimators/two_view.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>

#include "stitch/estimators/reprojection_error.h"
#include "stitch/estimators/triangulation.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

constexpr double kChi2OneDof = 3.841;  // 95%, one degree of freedom (epipolar distance)
constexpr double kChi2TwoDof = 5.991;  // 95%, two degrees of freedom (transfer error)

struct Candidate {
  Rigid3d cam2_from_cam1;
  std::vector<Eigen::Vector3d> points;
  std::vector<char> good;
  int num_good = 0;
  double parallax_deg = 0;
};

// Triangulates the inlier matches for one motion hypothesis and counts the good points: in front
// of both cameras, reprojection error under 2 sigma, and some parallax.
Candidate Check(const Rigid3d& cam2_from_cam1, const std::vector<Eigen::Vector2d>& p1,
                const std::vector<Eigen::Vector2d>& p2, const std::vector<char>& inlier, const PinholeIntrinsics& k,
                double sigma) {
  Candidate c;
  c.cam2_from_cam1 = cam2_from_cam1;
  c.points.assign(p1.size(), Eigen::Vector3d::Zero());
  c.good.assign(p1.size(), 0);
  const Rigid3d identity;
  const Eigen::Vector3d centre2 = cam2_from_cam1.CentreInWorld();
  const double max_error2 = 4.0 * sigma * sigma;
  std::vector<double> parallaxes;
  for (size_t i = 0; i < p1.size(); ++i) {
    if (!inlier[i]) continue;
    const auto x = TriangulateDlt(identity, k.Normalize(p1[i]), cam2_from_cam1, k.Normalize(p2[i]));
    if (!x) continue;
    const double cos_parallax = ParallaxCosine(*x, Eigen::Vector3d::Zero(), centre2);
    const Eigen::Vector3d in2 = cam2_from_cam1 * *x;
    // Points with almost no parallax can land behind a camera from noise alone; only points with
    // parallax must be in front (the others fail the reprojection test if they are far off).
    if ((x->z() <= 0 || in2.z() <= 0) && cos_parallax < 0.99998) continue;
    if ((k.Project(*x) - p1[i]).squaredNorm() > max_error2) continue;
    if ((k.Project(in2) - p2[i]).squaredNorm() > max_error2) continue;
    parallaxes.push_back(std::acos(std::clamp(cos_parallax, -1.0, 1.0)) * 180.0 / M_PI);
    c.points[i] = *x;
    ++c.num_good;
    c.good[i] = cos_parallax < 0.99998;  // only points with some parallax go into the map
  }
  if (!parallaxes.empty()) {
    std::sort(parallaxes.begin(), parallaxes.end(), std::greater<double>());
    c.parallax_deg = parallaxes[std::min<size_t>(50, parallaxes.size() - 1)];
  }
  return c;
}

// ORB-SLAM's model score: each match adds (5.991 - error^2 / sigma^2) per direction when the
// error is under the model's chi-square threshold.
double ScoreHomography(const Eigen::Matrix3d& h, const std::vector<Eigen::Vector2d>& p1,
                       const std::vector<Eigen::Vector2d>& p2, double sigma, std::vector<char>* inliers) {
  const Eigen::Matrix3d h_inv = h.inverse();
  const double inv_s2 = 1.0 / (sigma * sigma);
  double score = 0;
  inliers->assign(p1.size(), 0);
  for (size_t i = 0; i < p1.size(); ++i) {
    const Eigen::Vector3d a = h * p1[i].homogeneous();
    const Eigen::Vector3d b = h_inv * p2[i].homogeneous();
    const double e2 = (a.hnormalized() - p2[i]).squaredNorm() * inv_s2;
    const double e1 = (b.hnormalized() - p1[i]).squaredNorm() * inv_s2;
    bool in = true;
    if (e2 < kChi2TwoDof)
      score += kChi2TwoDof - e2;
    else
      in = false;
    if (e1 < kChi2TwoDof)
      score += kChi2TwoDof - e1;
    else
      in = false;
    (*inliers)[i] = in;
  }
  return score;
}

double ScoreFundamental(const Eigen::Matrix3d& f, const std::vector<Eigen::Vector2d>& p1,
                        const std::vector<Eigen::Vector2d>& p2, double sigma, std::vector<char>* inliers) {
  const double inv_s2 = 1.0 / (sigma * sigma);
  double score = 0;
  inliers->assign(p1.size(), 0);
  for (size_t i = 0; i < p1.size(); ++i) {
    const Eigen::Vector3d l2 = f * p1[i].homogeneous();  // line in image 2
    const Eigen::Vector3d l1 = f.transpose() * p2[i].homogeneous();
    const double d2 = std::pow(l2.dot(p2[i].homogeneous()), 2) / (l2.head<2>().squaredNorm() + 1e-18) * inv_s2;
    const double d1 = std::pow(l1.dot(p1[i].homogeneous()), 2) / (l1.head<2>().squaredNorm() + 1e-18) * inv_s2;
    bool in = true;
    if (d2 < kChi2OneDof)
      score += kChi2TwoDof - d2;
    else
      in = false;
    if (d1 < kChi2OneDof)
      score += kChi2TwoDof - d1;
    else
      in = false;
    (*inliers)[i] = in;
  }
  return score;
}

// Two-view bundle adjustment of the chosen motion: camera 1 fixed at the origin, the translation
// kept at unit length, the good points free. RANSAC's minimal-sample model is off by up to a
// degree with realistic noise; this brings it to the accuracy the data allows.
Rigid3d Refine(const Candidate& c, const std::vector<Eigen::Vector2d>& p1, const std::vector<Eigen::Vector2d>& p2,
               const PinholeIntrinsics& k, double sigma, double* final_cost = nullptr) {
  if (final_cost) *final_cost = 1e300;
  // Counted first: a loss function no residual took would be nobody's to delete.
  if (std::count_if(c.good.begin(), c.good.end(), [](char good) { return good != 0; }) < 8) return c.cam2_from_cam1;
  PoseParameters camera1((Rigid3d())), camera2(c.cam2_from_cam1);
  std::vector<Eigen::Vector3d> points = c.points;
  ceres::Problem problem;
  ceres::LossFunction* huber = new ceres::HuberLoss(std::sqrt(kChi2TwoDof));  // owned by `problem`
  for (size_t i = 0; i < points.size(); ++i) {
    if (!c.good[i]) continue;
    problem.AddResidualBlock(ReprojectionError::Create(p1[i], 1.0 / sigma, k.fx, k.fy, k.cx, k.cy), huber,
                             camera1.data(), points[i].data());
    problem.AddResidualBlock(ReprojectionError::Create(p2[i], 1.0 / sigma, k.fx, k.fy, k.cx, k.cy), huber,
                             camera2.data(), points[i].data());
  }
  problem.SetParameterBlockConstant(camera1.data());
  // The translation's scale is not observable: it stays of unit length.
  problem.SetManifold(camera2.data(),
                      new ceres::ProductManifold<ceres::EigenQuaternionManifold, ceres::SphereManifold<3>>);
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::DENSE_SCHUR;
  options.max_num_iterations = 20;
  options.num_threads = 1;
  options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  if (final_cost) *final_cost = summary.IsSolutionUsable() ? summary.final_cost : 1e300;
  if (!summary.IsSolutionUsable()) return c.cam2_from_cam1;
  Rigid3d refined = camera2.ToRigid();
  refined.translation.normalize();
  return refined;
}

Rigid3d ToRigid(const cv::Mat& r, const cv::Mat& t) {
  Eigen::Matrix3d rotation;
  Eigen::Vector3d translation;
  cv::cv2eigen(r, rotation);
  cv::cv2eigen(t, translation);
  const double norm = translation.norm();
  return Rigid3d(Eigen::Quaterniond(rotation).normalized(),
                 norm > 0 ? Eigen::Vector3d(translation / norm) : translation);
}

std::string TooLittleParallax(double parallax_deg, double needed_deg) {
  char text[80];
  std::snprintf(text, sizeof(text), "parallax %.2f deg, need %.2f", parallax_deg, needed_deg);
  return text;
}

}  // namespace

bool TwoViewOptions::Check(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (!(sigma_px > 0)) return fail("two_view.sigma_px must be > 0");
  if (!(min_parallax_deg >= 0)) return fail("two_view.min_parallax_deg must be >= 0");
  if (min_triangulated < 8) return fail("two_view.min_triangulated must be >= 8");
  if (!(homography_ratio > 0 && homography_ratio < 1)) return fail("two_view.homography_ratio must be in (0, 1)");
  if (!(min_good_fraction > 0 && min_good_fraction <= 1)) return fail("two_view.min_good_fraction must be in (0, 1]");
  return true;
}

std::optional<TwoViewResult> InitializeTwoView(const std::vector<Eigen::Vector2d>& p1,
                                               const std::vector<Eigen::Vector2d>& p2, const PinholeIntrinsics& k,
                                               const TwoViewOptions& options, std::string* why, bool essential_only) {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return std::nullopt;
  };
  if (p1.size() != p2.size()) throw Error("InitializeTwoView: unequal match lists");
  if (static_cast<int>(p1.size()) < options.min_triangulated) {
    return fail(std::to_string(p1.size()) + " matches, need " + std::to_string(options.min_triangulated));
  }
  std::vector<cv::Point2f> c1, c2;
  for (size_t i = 0; i < p1.size(); ++i) {
    c1.emplace_back(static_cast<float>(p1[i].x()), static_cast<float>(p1[i].y()));
    c2.emplace_back(static_cast<float>(p2[i].x()), static_cast<float>(p2[i].y()));
  }
  const double sigma = options.sigma_px;
  cv::Mat k_cv;
  cv::eigen2cv(k.K(), k_cv);
  // Both models from RANSAC; then both scored on all matches the same way.
  cv::Mat h_cv = cv::findHomography(c1, c2, cv::RANSAC, std::sqrt(kChi2TwoDof) * sigma, cv::noArray(), 2000, 0.999);
  cv::Mat e_cv = cv::findEssentialMat(c1, c2, k_cv, cv::RANSAC, 0.999, std::sqrt(kChi2OneDof) * sigma);
  if (e_cv.rows > 3) e_cv = e_cv.rowRange(0, 3);  // several solutions: keep the first
  double score_h = 0, score_f = 0;
  std::vector<char> inliers_h, inliers_f;
  Eigen::Matrix3d h = Eigen::Matrix3d::Identity(), e = Eigen::Matrix3d::Zero();
  if (!h_cv.empty()) {
    cv::cv2eigen(h_cv, h);
    score_h = ScoreHomography(h, p1, p2, sigma, &inliers_h);
  }
  if (!e_cv.empty()) {
    cv::cv2eigen(e_cv, e);
    const Eigen::Matrix3d k_inv = k.K().inverse();
    score_f = ScoreFundamental(k_inv.transpose() * e * k_inv, p1, p2, sigma, &inliers_f);
  }
  if (score_h + score_f <= 0) return fail("neither a homography nor an essential matrix explains the matches");
  const double homography_share = score_h / (score_h + score_f);
  // A camera moving toward the scene: the homography of a street or a wall ahead is no
  // reconstruction of the scene around it; the essential matrix, once its parallax allows.
  const bool use_h = !essential_only && homography_share > options.homography_ratio;

  std::vector<Candidate> candidates;
  int model_inliers = 0;
  if (use_h) {
    model_inliers = static_cast<int>(std::count(inliers_h.begin(), inliers_h.end(), 1));
    std::vector<cv::Mat> rotations, translations, normals;
    cv::decomposeHomographyMat(h_cv, k_cv, rotations, translations, normals);
    for (size_t s = 0; s < rotations.size(); ++s) {
      candidates.push_back(Check(ToRigid(rotations[s], translations[s]), p1, p2, inliers_h, k, sigma));
    }
  } else {
    model_inliers = static_cast<int>(std::count(inliers_f.begin(), inliers_f.end(), 1));
    cv::Mat r1, r2, t;
    cv::decomposeEssentialMat(e_cv, r1, r2, t);
    for (const cv::Mat& r : {r1, r2}) {
      for (double sign : {1.0, -1.0}) candidates.push_back(Check(ToRigid(r, sign * t), p1, p2, inliers_f, k, sigma));
    }
  }
  char share[64];
  std::snprintf(share, sizeof(share), " (homography's share of the score %.2f%s)", homography_share,
                essential_only ? ", forward" : "");
  const std::string model = (use_h ? "homography" : "essential matrix") + std::string(share);
  if (candidates.empty()) return fail(model + ": the model has no decomposition");
  // Only motions with parallax compete: a decomposition that explains the matches as an almost
  // pure rotation (points near infinity) is not a reconstruction. One with less parallax than the
  // threshold still competes in the ambiguity check below, and only the chosen motion must reach
  // it: the homography's twin solutions differ in parallax, and the true one may be far under the
  // threshold (a camera flying forward over flat ground sees little parallax near the direction
  // of flight, its twin much more: taken alone, the twin tilted the map's depth and its scale
  // collapsed as the flight went on).
  std::vector<Candidate> valid;
  for (const Candidate& c : candidates) {
    if (c.parallax_deg >= 0.1 * options.min_parallax_deg) valid.push_back(c);
  }
  if (valid.empty()) {
    double best_parallax = 0;
    for (const Candidate& c : candidates) best_parallax = std::max(best_parallax, c.parallax_deg);
    return fail(model + ": " + TooLittleParallax(best_parallax, options.min_parallax_deg));
  }
  std::sort(valid.begin(), valid.end(), [](const Candidate& a, const Candidate& b) { return a.num_good > b.num_good; });
  Candidate best = valid[0];
  const std::vector<char>& inliers = use_h ? inliers_h : inliers_f;
  if (valid.size() > 1 && valid[1].num_good > 0.9 * best.num_good) {
    // Two motions fit a (nearly) planar scene: the homography's twofold ambiguity. Where one of
    // them triangulates a tenth more of the matches well, the points off the plane (relief,
    // buildings) have decided. Otherwise refine both on their points: one that keeps clearly
    // more points well triangulated wins, then one that fits clearly better while keeping its
    // parallax (a twin may refine into a near-pure rotation, far points that fit any pair well,
    // and lose a third of its points doing it); failing that, the one that turns the camera
    // clearly less: the twin of a
    // camera moving along the ground turns it by about the baseline over the depth (4-17 degrees
    // against 0.1 for a forward camera, 2.5 against 0.7 looking down), while two frames a moment
    // apart are seldom turned much. Two motions that turn the camera alike are not twins but a
    // mostly rotating camera's small translation told two ways: the one with clearly more
    // parallax (and it must reach the threshold). Else the pair cannot tell, and a later frame may.
    double cost0 = 0, cost1 = 0;
    const Candidate r0 = Check(Refine(valid[0], p1, p2, k, sigma, &cost0), p1, p2, inliers, k, sigma);
    const Candidate r1 = Check(Refine(valid[1], p1, p2, k, sigma, &cost1), p1, p2, inliers, k, sigma);
    cost0 /= std::max(1, r0.num_good);
    cost1 /= std::max(1, r1.num_good);
    const auto turn = [](const Candidate& c) {
      return c.cam2_from_cam1.rotation.angularDistance(Eigen::Quaterniond::Identity());
    };
    if (r0.num_good > 1.2 * r1.num_good) {
      best = r0;
    } else if (r1.num_good > 1.2 * r0.num_good) {
      best = r1;
    } else if (cost0 < 0.5 * cost1 && r0.parallax_deg >= options.min_parallax_deg) {
      best = r0;
    } else if (cost1 < 0.5 * cost0 && r1.parallax_deg >= options.min_parallax_deg) {
      best = r1;
    } else if (turn(r0) < 0.5 * turn(r1)) {
      best = r0;
    } else if (turn(r1) < 0.5 * turn(r0)) {
      best = r1;
    } else if (r0.parallax_deg > 1.5 * r1.parallax_deg) {
      best = r0;
    } else if (r1.parallax_deg > 1.5 * r0.parallax_deg) {
      best = r1;
    } else {
      return fail(model + ": two motions explain the matches almost equally (" + std::to_string(valid[0].num_good) +
                  " vs " + std::to_string(valid[1].num_good) + " points)");
    }
  }
  if (best.parallax_deg < options.min_parallax_deg) {
    return fail(model + ": " + TooLittleParallax(best.parallax_deg, options.min_parallax_deg));
  }
  if (best.num_good < options.min_triangulated) {
    return fail(model + ": " + std::to_string(best.num_good) + " points triangulate, need " +
                std::to_string(options.min_triangulated));
  }
  if (best.num_good < options.min_good_fraction * model_inliers) {
    return fail(model + ": only " + std::to_string(best.num_good) + " of " + std::to_string(model_inliers) +
                " inliers triangulate well");
  }
  // Refine the motion, then triangulate again with it. The refined motion is the better
  // estimate: where it keeps the points but not the parallax, the unrefined one overstated the
  // baseline (a mostly rotating camera), and a later frame may do better.
  const Candidate refined = Check(Refine(best, p1, p2, k, sigma), p1, p2, inliers, k, sigma);
  const bool take_refined = refined.num_good >= best.num_good * 0.95;
  if (take_refined && refined.parallax_deg < options.min_parallax_deg) {
    return fail(model + ", refined: " + TooLittleParallax(refined.parallax_deg, options.min_parallax_deg));
  }
  const Candidate& chosen = take_refined ? refined : best;
  TwoViewResult result;
  result.cam2_from_cam1 = chosen.cam2_from_cam1;
  result.points_in_cam1 = chosen.points;
  result.triangulated = chosen.good;
  result.used_homography = use_h;
  result.homography_share = homography_share;
  result.parallax_deg = chosen.parallax_deg;
  result.num_triangulated = static_cast<int>(std::count(chosen.good.begin(), chosen.good.end(), 1));
  return result;
}

}  // namespace stitch
