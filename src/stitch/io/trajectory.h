#pragma once
// Timestamped camera poses, and the TUM trajectory format
// (`timestamp tx ty tz qx qy qz qw`, the pose being world_from_cam).

#include <cstdint>
#include <istream>
#include <optional>
#include <string>
#include <vector>

#include "stitch/geometry/rigid3.h"

namespace stitch {

struct StampedPose {
  int64_t t_ns = 0;
  Rigid3d world_from_cam;
};

// The seven TUM pose fields "tx ty tz qx qy qz qw" of a world_from_cam pose.
std::string FormatTumPose(const Rigid3d& world_from_cam);
// Reads them from `fields`; false when they are missing, or the quaternion is far from unit length.
bool ReadTumPose(std::istream& fields, Rigid3d* world_from_cam);

class Trajectory {
 public:
  Trajectory() = default;
  explicit Trajectory(std::vector<StampedPose> poses);  // sorts by time

  // Throws stitch::Error with the file and line for anything that is not a TUM line.
  static Trajectory ReadTum(const std::string& path);
  // `frame`, when given, goes into the header as "# frame: ..." (output_frames.h).
  void WriteTum(const std::string& path, const std::string& frame = "") const;

  const std::vector<StampedPose>& poses() const { return poses_; }
  bool empty() const { return poses_.empty(); }
  size_t size() const { return poses_.size(); }
  void Add(const StampedPose& pose);  // keeps the order
  // The samples from `first_ns` to `last_ns`, and the one on each side of that span (so that
  // PoseAt still interpolates at its ends).
  Trajectory Between(int64_t first_ns, int64_t last_ns) const;

  // Pose at t_ns: the sample itself if one lies within 1 us, otherwise interpolated between the
  // two samples around it (slerp) when they are at most `max_gap_ns` apart. Empty outside.
  std::optional<Rigid3d> PoseAt(int64_t t_ns, int64_t max_gap_ns = 50'000'000) const;

 private:
  std::vector<StampedPose> poses_;
};

}  // namespace stitch
