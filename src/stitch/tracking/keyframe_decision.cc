#include "stitch/tracking/keyframe_decision.h"

#include <cmath>

namespace stitch {

int ReferencePoints(const Map& map, const Keyframe& reference) {
  const int min_observations = map.num_keyframes() <= 2 ? 2 : 3;
  int count = 0;
  for (MapPointId p : reference.points) {
    const MapPoint* point = p.valid() ? map.FindPoint(p) : nullptr;
    if (point && static_cast<int>(point->observations.size()) >= min_observations) ++count;
  }
  return count;
}

bool NeedKeyframe(const KeyframeDecisionInput& input, const TrackingOptions& options, double fps) {
  if (!input.has_reference) return true;
  const int max_gap = options.max_keyframe_gap > 0 ? options.max_keyframe_gap : static_cast<int>(std::lround(fps));
  const bool long_gap = input.frames_since_keyframe >= max_gap;
  const bool few_tracked =
      input.tracked_points < options.keyframe_ratio * input.reference_points && input.tracked_points > 15;
  // As built: a long gap alone never makes a keyframe while the mapper is busy, and with the
  // mapper ready the gap does not matter, so the decision is few_tracked && mapper_ready.
  return (long_gap || input.mapper_ready) && few_tracked && input.mapper_ready;
}

}  // namespace stitch
