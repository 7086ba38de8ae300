#include "stitch/io/trajectory.h"

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "stitch/util/error.h"
#include "stitch/util/text_file.h"
#include "stitch/util/time.h"

namespace stitch {

Trajectory::Trajectory(std::vector<StampedPose> poses) : poses_(std::move(poses)) {
  std::stable_sort(poses_.begin(), poses_.end(),
                   [](const StampedPose& a, const StampedPose& b) { return a.t_ns < b.t_ns; });
}

void Trajectory::Add(const StampedPose& pose) {
  if (poses_.empty() || poses_.back().t_ns <= pose.t_ns) {
    poses_.push_back(pose);
    return;
  }
  const auto at = std::upper_bound(poses_.begin(), poses_.end(), pose.t_ns,
                                   [](int64_t t, const StampedPose& p) { return t < p.t_ns; });
  poses_.insert(at, pose);
}

std::string FormatTumPose(const Rigid3d& world_from_cam) {
  const auto& t = world_from_cam.translation;
  const auto& q = world_from_cam.rotation;
  char buffer[200];
  std::snprintf(buffer, sizeof(buffer), "%.9g %.9g %.9g %.9g %.9g %.9g %.9g", t.x(), t.y(), t.z(), q.x(), q.y(), q.z(),
                q.w());
  return buffer;
}

bool ReadTumPose(std::istream& fields, Rigid3d* world_from_cam) {
  double v[7];
  for (double& x : v) fields >> x;
  if (!fields) return false;
  const Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
  if (!(q.norm() > 0.5 && q.norm() < 1.5)) return false;
  *world_from_cam = Rigid3d(q.normalized(), Eigen::Vector3d(v[0], v[1], v[2]));
  return true;
}

Trajectory Trajectory::ReadTum(const std::string& path) {
  std::vector<StampedPose> poses;
  ForEachDataLine(
      path,
      [&](const std::string& line, int line_number) {
        std::istringstream fields(line);
        std::string stamp;
        StampedPose pose;
        fields >> stamp;
        if (!ReadTumPose(fields, &pose.world_from_cam)) {
          throw Error(Str() << path << ":" << line_number
                            << ": expected 'timestamp tx ty tz qx qy qz qw' (TUM format) with a unit quaternion");
        }
        try {
          pose.t_ns = ParseSecondsToNs(stamp);
        } catch (const Error& e) {
          throw Error(Str() << path << ":" << line_number << ": " << e.what());
        }
        poses.push_back(pose);
      },
      " (trajectory file)");
  return Trajectory(std::move(poses));
}

void Trajectory::WriteTum(const std::string& path, const std::string& frame) const {
  std::string text = "# timestamp tx ty tz qx qy qz qw (world_from_cam; seconds)\n";
  if (!frame.empty()) text += "# frame: " + frame + "\n";
  for (const auto& pose : poses_) text += FormatSeconds(pose.t_ns) + " " + FormatTumPose(pose.world_from_cam) + "\n";
  WriteFileAtomically(path, text);
}

Trajectory Trajectory::Between(int64_t first_ns, int64_t last_ns) const {
  const auto by_time = [](const StampedPose& p, int64_t t) { return p.t_ns < t; };
  auto begin = std::lower_bound(poses_.begin(), poses_.end(), first_ns, by_time);
  auto end = std::upper_bound(poses_.begin(), poses_.end(), last_ns,
                              [](int64_t t, const StampedPose& p) { return t < p.t_ns; });
  if (begin != poses_.begin()) --begin;
  if (end != poses_.end()) ++end;
  Trajectory clipped;
  clipped.poses_.assign(begin, end);
  return clipped;
}

std::optional<Rigid3d> Trajectory::PoseAt(int64_t t_ns, int64_t max_gap_ns) const {
  if (poses_.empty()) return std::nullopt;
  const auto after =
      std::lower_bound(poses_.begin(), poses_.end(), t_ns, [](const StampedPose& p, int64_t t) { return p.t_ns < t; });
  constexpr int64_t kSameSample = 1000;  // 1 us: timestamps printed with microseconds
  if (after != poses_.end() && after->t_ns - t_ns <= kSameSample) return after->world_from_cam;
  if (after != poses_.begin() && t_ns - std::prev(after)->t_ns <= kSameSample) {
    return std::prev(after)->world_from_cam;
  }
  if (after == poses_.end() || after == poses_.begin()) return std::nullopt;
  const StampedPose& a = *std::prev(after);
  const StampedPose& b = *after;
  if (b.t_ns - a.t_ns > max_gap_ns) return std::nullopt;
  const double alpha = static_cast<double>(t_ns - a.t_ns) / static_cast<double>(b.t_ns - a.t_ns);
  return Rigid3d(a.world_from_cam.rotation.slerp(alpha, b.world_from_cam.rotation),
                 (1 - alpha) * a.world_from_cam.translation + alpha * b.world_from_cam.translation);
}

}  // namespace stitch
