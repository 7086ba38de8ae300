#include "stitch/merging/merger.h"

#include <algorithm>
#include <cmath>
#include <set>

#include <Eigen/Eigenvalues>

#include "stitch/estimators/pnp.h"
#include "stitch/estimators/pose_optimizer.h"
#include "stitch/features/descriptor.h"
#include "stitch/map/matcher.h"
#include "stitch/merging/pose_graph.h"
#include "stitch/util/error.h"
#include "stitch/util/options.h"
#include "stitch/util/statistics.h"

namespace stitch {
namespace {

// Added to a saved map's keyframe count when the submaps are placed (more than any flight's).
constexpr int kSavedMapRootWeight = 1 << 24;

// A submap's own relative poses come from bundle adjustment over many points; a connected
// frame's Sim3 from a few dozen: the pose graph trusts the former more.
constexpr double kIntraSubmapWeight = 10.0;
// Connected frames that disagree with the tree's placement by more than this (and by more than
// kAgreeingRotationRad or kAgreeingLogScale) stay out of the pose graph. Measured on the default
// gust flight, correct connections disagree by at most 3 degrees, 12% of their translation and
// 0.016 in log scale (90%: 0.7 degrees, 2.4%, 0.006). The translation is measured against a
// tenth of the scene's depth where it is shorter.
constexpr double kMaxConnectionRelativeTranslation = 0.25;

// Shared-word counts as if each candidate had no more words than the query: a keyframe with twice
// the features (a submap's first two, made by initialization) shares more words with anything,
// and would otherwise win every query on its count alone.
void CountWordsAtTheQuerysSize(std::vector<KeyframeDatabase::Candidate>* candidates, size_t query_words,
                               const KeyframeDatabase& database) {
  for (auto& c : *candidates) {
    const BowVector* bow = database.Find(c.keyframe_id);
    if (!bow || bow->size() <= query_words) continue;
    c.common_words = static_cast<int>(std::lround(c.common_words * static_cast<double>(query_words) / bow->size()));
  }
}

// The adaptive thresholds of docs/method.md on database candidates: at least k x the best
// shared-word count, then at least l x the best score; the `keep` best by score remain. Returns
// how many passed k.
int ApplyAdaptiveThresholds(std::vector<KeyframeDatabase::Candidate>* candidates, double k, double l, int keep) {
  int most_words = 0;
  for (const auto& c : *candidates) most_words = std::max(most_words, c.common_words);
  candidates->erase(std::remove_if(candidates->begin(), candidates->end(),
                                   [&](const auto& c) { return c.common_words < k * most_words; }),
                    candidates->end());
  const int passed_k = static_cast<int>(candidates->size());
  double best_score = 0;
  for (const auto& c : *candidates) best_score = std::max(best_score, c.score);
  candidates->erase(
      std::remove_if(candidates->begin(), candidates->end(), [&](const auto& c) { return c.score < l * best_score; }),
      candidates->end());
  std::sort(candidates->begin(), candidates->end(), [](const auto& a, const auto& b) {
    return a.score > b.score || (a.score == b.score && a.keyframe_id < b.keyframe_id);
  });
  if (static_cast<int>(candidates->size()) > keep) candidates->resize(keep);
  return passed_k;
}

// The smaller principal standard deviation of 2D points.
double SmallerSpread(const std::vector<Eigen::Vector2d>& points) {
  if (points.size() < 2) return 0;
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Zero();
  for (const auto& p : points) covariance += (p - mean) * (p - mean).transpose();
  covariance /= static_cast<double>(points.size());
  return std::sqrt(std::max(0.0, Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(covariance).eigenvalues()(0)));
}

// The middle principal standard deviation of 3D points over the largest, over the 80% of the
// points nearest their median (a few points triangulated with little parallax lie far out along
// their rays and would make any cloud look like a line).
double LineRatio(std::vector<Eigen::Vector3d> points) {
  if (points.size() < 3) return 0;
  Eigen::Vector3d median;
  for (int axis = 0; axis < 3; ++axis) {
    std::vector<double> values;
    for (const auto& p : points) values.push_back(p(axis));
    median(axis) = Median(values);
  }
  std::sort(points.begin(), points.end(), [&](const Eigen::Vector3d& x, const Eigen::Vector3d& y) {
    return (x - median).squaredNorm() < (y - median).squaredNorm();
  });
  points.resize(std::max<size_t>(3, points.size() * 8 / 10));
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  for (const auto& p : points) covariance += (p - mean) * (p - mean).transpose();
  const Eigen::Vector3d values = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(covariance).eigenvalues();
  return values(2) > 0 ? std::sqrt(std::max(0.0, values(1)) / values(2)) : 0;
}

}  // namespace

ConnectionGeometry MeasureConnectionGeometry(const std::vector<Sim3Correspondence>& pairs,
                                             const std::vector<char>& inlier, const Sim3d& b_from_a,
                                             const Rigid3d& cam_b_from_b, const PinholeIntrinsics& k) {
  ConnectionGeometry g;
  std::vector<Eigen::Vector2d> bearings_a, bearings_b;
  std::vector<Eigen::Vector3d> points_a;
  std::vector<double> disagreement;
  const Eigen::Vector3d centre_b = cam_b_from_b.Inverse().translation;
  for (size_t m = 0; m < pairs.size(); ++m) {
    if (!inlier[m]) continue;
    const Sim3Correspondence& c = pairs[m];
    bearings_a.push_back(k.Normalize(c.pixel_a));
    bearings_b.push_back(k.Normalize(c.pixel_b));
    points_a.push_back(c.point_a);
    const double range = (c.point_b - centre_b).norm();
    if (range > 0) disagreement.push_back((b_from_a * c.point_a - c.point_b).norm() / range);
  }
  g.bearing_spread_a = SmallerSpread(bearings_a);
  g.bearing_spread_b = SmallerSpread(bearings_b);
  g.line_ratio = LineRatio(points_a);
  g.depth_disagreement = disagreement.empty() ? 0 : Median(disagreement);
  return g;
}

Merger::Merger(const MergerOptions& options, const Vocabulary* vocabulary, const ScalePyramid& pyramid)
    : options_(options), vocabulary_(vocabulary), pyramid_(pyramid) {
  CheckOptions(options_, "merger");
  if (!vocabulary_ || vocabulary_->empty()) throw Error("the merger needs a vocabulary");
}

const Undistorter& Merger::UndistorterFor(const Camera& camera) {
  const std::string key = camera.Describe();
  auto it = undistorters_.find(key);
  if (it == undistorters_.end()) it = undistorters_.emplace(key, Undistorter(camera)).first;
  return it->second;
}

std::vector<KeyframeId> Merger::Apply(const SubmapUpdate& update) {
  if (!update.submap.valid()) return {};
  SubmapReplica& replica = submaps_.try_emplace(update.submap, update.submap, pyramid_).first->second;
  const std::vector<KeyframeId> missing = ApplySubmapUpdate(update, &replica);
  // Keyframes the mapper culled leave the database too.
  const auto first = prepared_.lower_bound(MakeKeyframeId(update.submap, 0));
  std::vector<KeyframeId> gone;
  for (auto it = first; it != prepared_.end() && SubmapOf(*it) == update.submap; ++it) {
    if (!replica.map.FindKeyframe(*it)) gone.push_back(*it);
  }
  for (KeyframeId id : gone) {
    database_.Remove(id.value);
    prepared_.erase(id);
  }
  if (!replica.camera) return missing;
  std::vector<KeyframeId> fresh;
  for (const auto& [id, keyframe] : replica.map.keyframes()) {
    if (!prepared_.count(id)) fresh.push_back(id);
  }
  std::sort(fresh.begin(), fresh.end());
  for (KeyframeId id : fresh) Prepare(&replica, replica.map.FindKeyframe(id));
  for (KeyframeId id : fresh) retrievals_.push_back(Retrieve(replica, *replica.map.FindKeyframe(id)));
  return missing;
}

void Merger::Prepare(SubmapReplica* replica, Keyframe* keyframe) {
  const Undistorter& undistorter = UndistorterFor(*replica->camera);
  keyframe->undistorted.clear();
  for (const auto& k : keyframe->keypoints) keyframe->undistorted.push_back(undistorter.Undistort(k.pt.x, k.pt.y));
  keyframe->grid = FeatureGrid(keyframe->undistorted, undistorter);
  keyframe->bow = vocabulary_->Transform(keyframe->descriptors, &keyframe->bow_features);
  database_.Add(keyframe->id.value, replica->map.id().value, keyframe->bow);
  prepared_.insert(keyframe->id);
}

RetrievalRecord Merger::Retrieve(const SubmapReplica& replica, const Keyframe& keyframe) {
  RetrievalRecord r;
  r.keyframe = keyframe.id;
  const Map& map = replica.map;
  for (const auto& [id, other] : map.keyframes()) {
    if (id < keyframe.id && (!r.previous.valid() || r.previous < id) && prepared_.count(id)) r.previous = id;
  }
  if (!r.previous.valid()) {
    r.skipped = "first keyframe of its submap";
    return r;
  }
  // The nearby keyframe: the covisible one whose shared points are closest to half of ours.
  const double own = std::max(1, keyframe.CountPoints());
  double closest = 2;
  for (const auto& [id, shared] : keyframe.covisibility) {
    const double distance = std::abs(shared / own - 0.5);
    if (prepared_.count(id) && distance < closest) {
      closest = distance;
      r.nearby = id;
    }
  }
  if (!r.nearby.valid()) {
    r.skipped = "no covisible keyframe";
    return r;
  }
  const Keyframe& previous = *map.FindKeyframe(r.previous);
  const Keyframe& nearby = *map.FindKeyframe(r.nearby);
  r.n0 = CommonWords(keyframe.bow, previous.bow);
  r.s0 = ScoreL1(keyframe.bow, previous.bow);
  r.n1 = CommonWords(keyframe.bow, nearby.bow);
  r.s1 = ScoreL1(keyframe.bow, nearby.bow);
  if (r.n0 == 0 || !(r.s0 > 0)) {
    r.skipped = "no word shared with the previous keyframe";
    return r;
  }
  r.k = std::min(1.0, static_cast<double>(r.n1) / r.n0);
  r.l = std::min(1.0, r.s1 / r.s0);
  const int64_t own_submap = map.id().value;
  std::vector<KeyframeDatabase::Candidate> candidates =
      database_.Query(keyframe.bow, [own_submap](int64_t submap) { return submap != own_submap; });
  if (candidates.empty()) r.skipped = "no other submap shares a word";
  CountWordsAtTheQuerysSize(&candidates, keyframe.bow.size(), database_);
  r.shared_word_candidates = ApplyAdaptiveThresholds(&candidates, r.k, r.l, options_.max_candidates);
  for (const auto& c : candidates) {
    const KeyframeId id(c.keyframe_id);
    r.candidates.push_back(id);
    const auto other = submaps_.find(SubmapId(c.submap_id));
    if (other == submaps_.end() || !other->second.camera) continue;
    const Keyframe* candidate = other->second.map.FindKeyframe(id);
    if (!candidate) continue;
    int matches = 0, inliers = 0;
    if (auto connection = Verify(replica, keyframe, other->second, *candidate, &matches, &inliers)) {
      if (File(std::move(*connection), &connections_)) r.connected.push_back(id);
    }
    r.verification.push_back({matches, inliers});
  }
  if (options_.loop_closure) RetrieveLoops(replica, keyframe, &r);
  return r;
}

void Merger::RetrieveLoops(const SubmapReplica& replica, const Keyframe& keyframe, RetrievalRecord* r) {
  const int64_t own_submap = replica.map.id().value;
  std::vector<KeyframeDatabase::Candidate> candidates =
      database_.Query(keyframe.bow, [own_submap](int64_t submap) { return submap == own_submap; });
  // Away from the covisible window: no shared point, and far back in the submap.
  candidates.erase(std::remove_if(candidates.begin(), candidates.end(),
                                  [&](const auto& c) {
                                    const KeyframeId id(c.keyframe_id);
                                    return keyframe.covisibility.count(id) ||
                                           static_cast<int64_t>(IndexOf(id)) + options_.loop_min_separation >
                                               static_cast<int64_t>(IndexOf(keyframe.id));
                                  }),
                   candidates.end());
  CountWordsAtTheQuerysSize(&candidates, keyframe.bow.size(), database_);
  ApplyAdaptiveThresholds(&candidates, r->k, r->l, options_.max_candidates);
  for (const auto& c : candidates) {
    const KeyframeId id(c.keyframe_id);
    r->loop_candidates.push_back(id);
    const Keyframe* candidate = replica.map.FindKeyframe(id);
    if (!candidate) continue;
    int matches = 0, inliers = 0;
    if (auto loop = Verify(replica, keyframe, replica, *candidate, &matches, &inliers)) {
      if (File(std::move(*loop), &loops_)) r->loops.push_back(id);
    }
    r->verification.push_back({matches, inliers});
  }
}

std::optional<ConnectedFrame> Merger::Verify(const SubmapReplica& a, const Keyframe& keyframe_a, const SubmapReplica& b,
                                             const Keyframe& keyframe_b, int* match_count, int* inlier_count) const {
  const PinholeIntrinsics k = a.camera->Intrinsics();
  const auto matches = MatchKeyframesByBow(keyframe_a, a.map, keyframe_b, b.map, options_.match_ratio);
  std::vector<Sim3Correspondence> pairs;
  std::vector<std::pair<MapPointId, MapPointId>> point_ids;
  std::vector<char> used_a(keyframe_a.keypoints.size(), 0), used_b(keyframe_b.keypoints.size(), 0);
  std::set<MapPointId> used_points_b;
  for (const auto& [i, j] : matches) {
    point_ids.push_back({keyframe_a.points[i], keyframe_b.points[j]});
    Sim3Correspondence c;
    c.point_a = a.map.FindPoint(keyframe_a.points[i])->position;
    c.point_b = b.map.FindPoint(keyframe_b.points[j])->position;
    c.pixel_a = keyframe_a.undistorted[i];
    c.pixel_b = keyframe_b.undistorted[j];
    c.sigma2_a = pyramid_.sigma2[keyframe_a.keypoints[i].octave];
    c.sigma2_b = pyramid_.sigma2[keyframe_b.keypoints[j].octave];
    pairs.push_back(c);
    used_a[i] = used_b[j] = 1;
    used_points_b.insert(keyframe_b.points[j]);
  }
  if (static_cast<int>(pairs.size()) < options_.min_matches && options_.candidate_window > 0) {
    // The candidate alone holds too few of the place's points (an initial keyframe, or one whose
    // points the mapper moved to its neighbours): its best covisible keyframes see the same
    // place, and their points count too. A point b's keyframe does not observe is compared where
    // it projects in that keyframe.
    for (KeyframeId id : b.map.BestCovisible(keyframe_b.id, options_.candidate_window)) {
      const Keyframe* neighbour = b.map.FindKeyframe(id);
      if (!neighbour || !prepared_.count(id)) continue;
      for (const auto& [i, j] : MatchKeyframesByBow(keyframe_a, a.map, *neighbour, b.map, options_.match_ratio)) {
        const MapPointId id_b = neighbour->points[j];
        if (used_a[i] || used_points_b.count(id_b)) continue;
        const MapPoint* point_b = b.map.FindPoint(id_b);
        const Eigen::Vector3d in_b = keyframe_b.cam_from_world * point_b->position;
        if (in_b.z() <= 0) continue;
        Sim3Correspondence c;
        c.point_a = a.map.FindPoint(keyframe_a.points[i])->position;
        c.point_b = point_b->position;
        c.pixel_a = keyframe_a.undistorted[i];
        c.pixel_b = k.Project(in_b);
        c.sigma2_a = pyramid_.sigma2[keyframe_a.keypoints[i].octave];
        c.sigma2_b = pyramid_.sigma2[neighbour->keypoints[j].octave];
        pairs.push_back(c);
        point_ids.push_back({keyframe_a.points[i], id_b});
        used_a[i] = 1;
        used_points_b.insert(id_b);
      }
    }
    for (size_t j = 0; j < keyframe_b.points.size(); ++j) used_b[j] |= used_points_b.count(keyframe_b.points[j]) > 0;
  }
  *match_count = static_cast<int>(pairs.size());
  if (static_cast<int>(pairs.size()) < options_.min_matches) return std::nullopt;
  Sim3Options sim3;
  sim3.min_inliers = options_.sim3_min_inliers;
  sim3.seed = static_cast<uint64_t>(keyframe_a.id.value ^ (keyframe_b.id.value << 1));
  std::optional<Sim3Estimate> estimate;
  VerifiedBy verified_by = VerifiedBy::kDescriptors;
  if (static_cast<int>(pairs.size()) >= options_.sim3_min_inliers) {
    estimate = EstimateSim3(pairs, keyframe_a.cam_from_world, keyframe_b.cam_from_world, k, sim3, inlier_count);
  }
  if (!estimate && options_.match_by_projection) {
    verified_by = VerifiedBy::kProjection;
    estimate = VerifyByProjection(a, keyframe_a, b, keyframe_b, &used_a, &used_b, &pairs, &point_ids, inlier_count);
  }
  if (!estimate && options_.relocalization_min_inliers > 0) {
    verified_by = VerifiedBy::kRelocalization;
    estimate = VerifyByRelocalization(keyframe_a, k, pairs, inlier_count);
  }
  if (!estimate) return std::nullopt;
  ConnectedFrame connection;
  connection.geometry =
      MeasureConnectionGeometry(pairs, estimate->inlier, estimate->b_from_a, keyframe_b.cam_from_world, k);
  connection.geometry.verified_by = verified_by;
  connection.revision_a = a.newest_revision;
  connection.revision_b = b.newest_revision;
  connection.keyframe_a = keyframe_a.id;
  connection.keyframe_b = keyframe_b.id;
  connection.b_from_a = estimate->b_from_a;
  connection.map_points = estimate->num_inliers;
  // Intersection angles in a's frame: rays from the two camera centres to each agreeing point.
  const Eigen::Vector3d centre_a = keyframe_a.Centre();
  const Eigen::Vector3d centre_b = estimate->b_from_a.Inverse() * keyframe_b.Centre();
  std::vector<double> angles;
  for (size_t m = 0; m < pairs.size(); ++m) {
    if (!estimate->inlier[m]) continue;
    connection.point_pairs.push_back(point_ids[m]);
    const Eigen::Vector3d ray_a = (pairs[m].point_a - centre_a).normalized();
    const Eigen::Vector3d ray_b = (pairs[m].point_a - centre_b).normalized();
    angles.push_back(std::acos(std::clamp(ray_a.dot(ray_b), -1.0, 1.0)) * 180.0 / M_PI);
  }
  connection.median_angle_deg = Median(angles);
  return connection;
}

// Too few descriptor matches agree: a first similarity from fewer, then more matches by
// projecting the candidate's points with it (as ORB-SLAM's SearchBySim3), then the similarity
// from all of them, which must reach the full inlier count.
std::optional<Sim3Estimate> Merger::VerifyByProjection(const SubmapReplica& a, const Keyframe& keyframe_a,
                                                       const SubmapReplica& b, const Keyframe& keyframe_b,
                                                       std::vector<char>* matched_a, std::vector<char>* matched_b,
                                                       std::vector<Sim3Correspondence>* correspondences,
                                                       std::vector<std::pair<MapPointId, MapPointId>>* point_ids,
                                                       int* inlier_count) const {
  std::vector<Sim3Correspondence>& pairs = *correspondences;
  const PinholeIntrinsics k = a.camera->Intrinsics();
  Sim3Options first_guess;
  first_guess.min_inliers = std::max(6, options_.sim3_min_inliers / 2);
  first_guess.seed = static_cast<uint64_t>(keyframe_a.id.value ^ (keyframe_b.id.value << 1));
  const auto guess =
      EstimateSim3(pairs, keyframe_a.cam_from_world, keyframe_b.cam_from_world, k, first_guess, inlier_count);
  if (!guess) return std::nullopt;
  std::vector<char>& used_a = *matched_a;
  const std::vector<char>& used_b = *matched_b;
  const Sim3d a_from_b = guess->b_from_a.Inverse();
  for (size_t j = 0; j < keyframe_b.keypoints.size(); ++j) {
    const MapPoint* point_b = keyframe_b.points[j].valid() ? b.map.FindPoint(keyframe_b.points[j]) : nullptr;
    if (used_b[j] || !point_b) continue;
    const Eigen::Vector3d in_cam_a = keyframe_a.cam_from_world * (a_from_b * point_b->position);
    if (in_cam_a.z() <= 0) continue;
    const Eigen::Vector2d pixel = k.Project(in_cam_a);
    const double radius = 7.5 * pyramid_.scale[keyframe_b.keypoints[j].octave];
    int best = 101, best_index = -1;
    for (int i : keyframe_a.grid.InArea(pixel.x(), pixel.y(), radius, keyframe_a.keypoints, keyframe_a.undistorted)) {
      const MapPoint* point_a = keyframe_a.points[i].valid() ? a.map.FindPoint(keyframe_a.points[i]) : nullptr;
      if (used_a[i] || !point_a) continue;
      const int d = HammingDistance(point_b->descriptor.data(), keyframe_a.descriptors.ptr<uint8_t>(i));
      if (d < best) {
        best = d;
        best_index = i;
      }
    }
    if (best_index < 0 || best > 100) continue;
    used_a[best_index] = 1;
    Sim3Correspondence c;
    c.point_a = a.map.FindPoint(keyframe_a.points[best_index])->position;
    c.point_b = point_b->position;
    c.pixel_a = keyframe_a.undistorted[best_index];
    c.pixel_b = keyframe_b.undistorted[j];
    c.sigma2_a = pyramid_.sigma2[keyframe_a.keypoints[best_index].octave];
    c.sigma2_b = pyramid_.sigma2[keyframe_b.keypoints[j].octave];
    pairs.push_back(c);
    point_ids->push_back({keyframe_a.points[best_index], keyframe_b.points[j]});
  }
  Sim3Options sim3;
  sim3.min_inliers = options_.sim3_min_inliers;
  sim3.seed = first_guess.seed;
  return EstimateSim3(pairs, keyframe_a.cam_from_world, keyframe_b.cam_from_world, k, sim3, inlier_count);
}

// The points of both submaps agree on where they are seen from, but not closely enough on where
// they are in 3D (points triangulated with little parallax: a camera that mostly rotates) for a
// similarity to reproject them in both keyframes. Relocalize keyframe a in submap b as the
// tracker would (PnP RANSAC on its own pixels and b's points, then the pose optimized): a pose
// that many points confirm is a verified connection; the scale between the submaps is the median
// ratio of the points' distances from the camera in the two.
std::optional<Sim3Estimate> Merger::VerifyByRelocalization(const Keyframe& keyframe_a, const PinholeIntrinsics& k,
                                                           const std::vector<Sim3Correspondence>& pairs,
                                                           int* inlier_count) const {
  std::vector<PnpMatch> matches;
  for (const Sim3Correspondence& c : pairs) matches.push_back({c.pixel_a, c.point_b, std::sqrt(c.sigma2_a)});
  PnpOptions pnp_options;
  pnp_options.min_inliers = options_.relocalization_min_inliers / 2;
  const std::optional<PnpResult> pnp = EstimatePoseRansac(matches, k, pnp_options);
  if (!pnp) return std::nullopt;
  std::vector<PoseObservation> observations;
  for (const Sim3Correspondence& c : pairs) observations.push_back({c.pixel_a, c.point_b, 1.0 / c.sigma2_a});
  const PoseOptimizerResult optimized = OptimizePose(observations, pnp->cam_from_world, k);
  *inlier_count = optimized.num_inliers;
  if (!optimized.converged || optimized.num_inliers < options_.relocalization_min_inliers) return std::nullopt;
  const Rigid3d& cam_from_b = optimized.cam_from_world;
  const Rigid3d& cam_from_a = keyframe_a.cam_from_world;
  std::vector<double> ratios;
  for (size_t m = 0; m < pairs.size(); ++m) {
    if (!optimized.inlier[m]) continue;
    const double in_a = (cam_from_a * pairs[m].point_a).norm(), in_b = (cam_from_b * pairs[m].point_b).norm();
    if (in_a > 0 && in_b > 0) ratios.push_back(in_b / in_a);
  }
  if (ratios.empty()) return std::nullopt;
  const double scale = Median(ratios);  // b's units per a's
  const Rigid3d b_from_cam = cam_from_b.Inverse();
  Sim3Estimate estimate;
  estimate.b_from_a = Sim3d(1.0, b_from_cam.rotation, b_from_cam.translation) *
                      Sim3d(scale, Eigen::Quaterniond::Identity(), Eigen::Vector3d::Zero()) *
                      Sim3d(1.0, cam_from_a.rotation, cam_from_a.translation);
  estimate.inlier = optimized.inlier;
  estimate.num_inliers = optimized.num_inliers;
  return estimate;
}

bool Merger::File(ConnectedFrame connection, std::vector<ConnectedFrame>* accepted) {
  connection.refused = RefuseConnection(connection.geometry, options_.acceptance);
  if (!connection.refused.empty()) {
    refused_.push_back(std::move(connection));
    return false;
  }
  accepted->push_back(std::move(connection));
  return true;
}

Merger::Reverification Merger::ReverifyStaleConnections() {
  Reverification result;
  if (!options_.acceptance.reverify_stale_connections) return result;
  std::vector<ConnectedFrame> all;
  for (std::vector<ConnectedFrame>* list : {&connections_, &loops_, &refused_}) {
    for (ConnectedFrame& c : *list) all.push_back(std::move(c));
    list->clear();
  }
  for (ConnectedFrame& c : all) {
    const bool loop = SubmapOf(c.keyframe_a) == SubmapOf(c.keyframe_b);
    std::vector<ConnectedFrame>* accepted = loop ? &loops_ : &connections_;
    const SubmapReplica& a = submaps_.at(SubmapOf(c.keyframe_a));
    const SubmapReplica& b = submaps_.at(SubmapOf(c.keyframe_b));
    if (c.revision_a == a.newest_revision && c.revision_b == b.newest_revision) {
      (c.refused.empty() ? accepted : &refused_)->push_back(std::move(c));
      continue;
    }
    const Keyframe* keyframe_a = a.map.FindKeyframe(c.keyframe_a);
    const Keyframe* keyframe_b = b.map.FindKeyframe(c.keyframe_b);
    ++result.reverified;
    int matches = 0, inliers = 0;
    std::optional<ConnectedFrame> again;
    if (keyframe_a && keyframe_b && prepared_.count(c.keyframe_a) && prepared_.count(c.keyframe_b)) {
      again = Verify(a, *keyframe_a, b, *keyframe_b, &matches, &inliers);
    }
    if (!again) {
      // Nothing newer to go by: kept, marked stale, and tried again when its submaps change.
      ++result.stale;
      c.stale = true;
      c.revision_a = a.newest_revision;
      c.revision_b = b.newest_revision;
      (c.refused.empty() ? accepted : &refused_)->push_back(std::move(c));
      continue;
    }
    if (!SimilaritiesAgree(c.b_from_a, again->b_from_a)) ++result.changed;
    File(std::move(*again), accepted);
  }
  return result;
}

SubmapCompleteness CompletenessOf(const SubmapReplica& replica) {
  SubmapCompleteness c;
  c.listed = static_cast<int>(replica.manifest.size());
  for (KeyframeId id : replica.manifest) c.missing += replica.map.FindKeyframe(id) == nullptr;
  return c;
}

Merger::Graph Merger::Solve(bool refine, const SubmapFixes& gnss) const {
  Graph graph;
  graph.edges = SummarizeConnections(connections_, options_.connection_weights);
  std::vector<SubmapId> ids;
  std::map<SubmapId, int> keyframes;
  std::map<SubmapId, SubmapCompleteness> completeness;
  for (const auto& [id, replica] : submaps_) {
    ids.push_back(id);
    // A saved map (merger.prior_map) counts as the largest: it roots its merged map, which keeps
    // the saved map's frame and comes first.
    keyframes[id] = static_cast<int>(replica.map.num_keyframes()) + (IsSavedMap(id) ? kSavedMapRootWeight : 0);
    completeness[id] = CompletenessOf(replica);
  }
  CheckEdges(&graph.edges, options_.min_connection_strength, options_.acceptance);
  CheckCompleteness(&graph.edges, options_.min_connection_strength, completeness,
                    options_.acceptance.max_missing_keyframes);
  for (SubmapEdge& e : graph.edges) {
    const auto refusal = refused_after_placement_.find(SubmapPair(e.a, e.b));
    if (e.refused.empty() && refusal != refused_after_placement_.end() &&
        e.connected_frames <= refusal->second.connected_frames) {
      e.refused = refusal->second.reason;
    }
  }
  graph.tree = MinimumSpanningForest(ids, graph.edges, options_.min_connection_strength);
  graph.placement = PlaceSubmaps(keyframes, graph.tree);
  CheckCycles(&graph.edges, graph.tree, graph.placement);
  if (!gnss.empty() && options_.join_by_gnss && options_.georeference.enabled) {
    GnssJoining joining = JoinByGnss(submaps_, graph.placement, gnss, options_.georeference);
    graph.not_joined_by_gnss = std::move(joining.not_joined);
    if (!joining.junctions.empty()) {
      const std::map<SubmapId, SubmapPlacement> by_views = graph.placement;
      graph.edges.insert(graph.edges.end(), joining.junctions.begin(), joining.junctions.end());
      graph.tree.insert(graph.tree.end(), joining.junctions.begin(), joining.junctions.end());
      graph.placement = PlaceSubmaps(keyframes, graph.tree);
      for (auto& [id, place] : graph.placement) place.anchor = by_views.at(id).root;
    }
    graph.on_earth = MapsOnEarth(joining.placements, graph.placement);
  }
  if (refine) graph.keyframe_poses = RefineKeyframePoses(graph.placement, &graph);
  return graph;
}

void Merger::RefuseAfterPlacement(const SubmapEdge& edge, const std::string& reason) {
  refused_after_placement_[SubmapPair(edge.a, edge.b)] = {edge.connected_frames, reason};
}

std::map<KeyframeId, Sim3d> Merger::RefineKeyframePoses(const std::map<SubmapId, SubmapPlacement>& placement,
                                                        Graph* graph) const {
  const auto as_sim3 = [](const Rigid3d& r) { return Sim3d(1.0, r.rotation, r.translation); };
  std::map<KeyframeId, Sim3d> poses;
  std::vector<KeyframeId> fixed;
  std::vector<PoseGraphEdge> edges;
  for (const auto& [id, replica] : submaps_) {
    const SubmapPlacement& place = placement.at(id);
    const Map& map = replica.map;
    KeyframeId first;
    for (const auto& [kf_id, keyframe] : map.keyframes()) {
      poses[kf_id] = place.world_from_submap * as_sim3(keyframe.cam_from_world.Inverse());
      if (!first.valid() || kf_id < first) first = kf_id;
    }
    if (id == place.Anchor() && first.valid()) fixed.push_back(first);
    // Within the submap: its strongest covisibility links and consecutive keyframes, as measured
    // by its own poses.
    KeyframeId previous;
    std::vector<KeyframeId> ordered_ids;
    for (const auto& [kf_id, keyframe] : map.keyframes()) ordered_ids.push_back(kf_id);
    std::sort(ordered_ids.begin(), ordered_ids.end());
    for (KeyframeId kf_id : ordered_ids) {
      const Keyframe& keyframe = *map.FindKeyframe(kf_id);
      const auto link = [&](KeyframeId other_id) {
        const Keyframe* other = map.FindKeyframe(other_id);
        if (!other) return;
        edges.push_back(
            {kf_id, other_id, as_sim3(keyframe.cam_from_world * other->cam_from_world.Inverse()), kIntraSubmapWeight});
      };
      if (previous.valid()) link(previous);
      for (size_t n = 0; n < keyframe.ordered.size(); ++n) {
        const auto& [weight, other] = keyframe.ordered[n];
        if (other < kf_id && (weight >= 100 || n == 0) && other != previous) link(other);
      }
      previous = kf_id;
    }
  }
  // Between submaps of one merged map: every verified connected frame.
  for (const ConnectedFrame& c : connections_) {
    const SubmapId a = SubmapOf(c.keyframe_a), b = SubmapOf(c.keyframe_b);
    const auto pa = placement.find(a), pb = placement.find(b);
    if (pa == placement.end() || pb == placement.end() || pa->second.component != pb->second.component) continue;
    const Keyframe* ka = submaps_.at(a).map.FindKeyframe(c.keyframe_a);
    const Keyframe* kb = submaps_.at(b).map.FindKeyframe(c.keyframe_b);
    if (!ka || !kb) {
      // A keyframe the mapper has culled since: no pose to join in the graph, but its matched
      // points remain, and fusing by projection around the keyframes that see them joins the two
      // submaps (which the check after placement needs) if its similarity agrees with the
      // placement. On a rotating camera the mapper culls most keyframes, and with them those of
      // most connected frames (docs/merger.md).
      const Sim3d placed_b_from_a = pb->second.world_from_submap.Inverse() * pa->second.world_from_submap;
      if (SimilaritiesAgree(c.b_from_a, placed_b_from_a)) graph->agreeing.push_back(c);
      continue;
    }
    const Sim3d measured = as_sim3(ka->cam_from_world) * c.b_from_a.Inverse() * as_sim3(kb->cam_from_world.Inverse());
    // A connection that disagrees with the placement along the tree is left out: a wrong one
    // would bend the submaps it joins (see merger.md for the thresholds' origin).
    const Sim3d placed = poses[c.keyframe_a].Inverse() * poses[c.keyframe_b];
    // Against the scene's depth where the keyframes are nearer each other than a tenth of it: a
    // rotating camera's connected keyframes can be millimetres apart.
    const double depth = submaps_.at(a).map.MedianDepth(c.keyframe_a);
    const double relative_translation =
        (placed.translation - measured.translation).norm() / std::max({measured.translation.norm(), 0.1 * depth, 1e-3});
    if (!SimilaritiesAgree(measured, placed) || relative_translation > kMaxConnectionRelativeTranslation) {
      continue;
    }
    edges.push_back({c.keyframe_a, c.keyframe_b, measured, 1.0, /*robust=*/true});
    graph->agreeing.push_back(c);
  }
  // Within a submap: confirmed loops (they measure the drift, so no check against the placement).
  for (const ConnectedFrame& c : ConfirmedLoops()) {
    const Map& map = submaps_.at(SubmapOf(c.keyframe_a)).map;
    const Keyframe* ka = map.FindKeyframe(c.keyframe_a);
    const Keyframe* kb = map.FindKeyframe(c.keyframe_b);
    if (!ka || !kb) continue;
    const Sim3d measured = as_sim3(ka->cam_from_world) * c.b_from_a.Inverse() * as_sim3(kb->cam_from_world.Inverse());
    // Confirmed, so weighted as the submap's own edges, without the robust cost that would
    // shrug off the large error a loop is there to correct.
    edges.push_back({c.keyframe_a, c.keyframe_b, measured, kIntraSubmapWeight, /*robust=*/false});
    graph->agreeing.push_back(c);
    ++graph->loops_used;
  }
  OptimizePoseGraph(&poses, edges, fixed);
  return poses;
}

std::vector<ConnectedFrame> Merger::ConfirmedLoops() const {
  // A loop is confirmed by another whose ends are near its own (in the keyframes' numbering) and
  // whose correction agrees: a wrong loop rarely repeats itself.
  constexpr uint32_t kNearKeyframes = 8;
  constexpr double kMaxRotationRad = 2.0 * M_PI / 180.0;
  constexpr double kMaxLogScale = 0.05;
  constexpr double kMaxShiftOfDepth = 0.1;  // of the keyframe's median depth
  const auto near = [](KeyframeId a, KeyframeId b) {
    return SubmapOf(a) == SubmapOf(b) &&
           std::max(IndexOf(a), IndexOf(b)) - std::min(IndexOf(a), IndexOf(b)) <= kNearKeyframes;
  };
  std::vector<ConnectedFrame> confirmed;
  for (size_t i = 0; i < loops_.size(); ++i) {
    const ConnectedFrame& loop = loops_[i];
    const Map& map = submaps_.at(SubmapOf(loop.keyframe_a)).map;
    const Keyframe* keyframe = map.FindKeyframe(loop.keyframe_a);
    if (!keyframe || !map.FindKeyframe(loop.keyframe_b)) continue;
    const Eigen::Vector3d centre = keyframe->Centre();
    const double depth = map.MedianDepth(loop.keyframe_a);
    for (size_t j = 0; j < loops_.size(); ++j) {
      const ConnectedFrame& other = loops_[j];
      if (i == j || other.keyframe_a == loop.keyframe_a || !near(other.keyframe_a, loop.keyframe_a) ||
          !near(other.keyframe_b, loop.keyframe_b)) {
        continue;
      }
      const Sim3d difference = loop.b_from_a.Inverse() * other.b_from_a;
      if (RotationAngle(difference.rotation) < kMaxRotationRad && std::abs(std::log(difference.scale)) < kMaxLogScale &&
          (loop.b_from_a * centre - other.b_from_a * centre).norm() < kMaxShiftOfDepth * depth) {
        confirmed.push_back(loop);
        break;
      }
    }
  }
  return confirmed;
}

}  // namespace stitch
