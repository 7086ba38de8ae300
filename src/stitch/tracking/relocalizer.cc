#include "stitch/tracking/relocalizer.h"

#include <algorithm>

#include "stitch/map/matcher.h"

namespace stitch {

Relocalizer::Relocalizer(const TrackingOptions& options, FramePlacer* placer, const Vocabulary* vocabulary,
                         std::function<void()> wait_for_keyframe_bow)
    : options_(options),
      placer_(placer),
      vocabulary_(vocabulary),
      wait_for_keyframe_bow_(std::move(wait_for_keyframe_bow)) {}

std::optional<KeyframeId> Relocalizer::Relocalize(Frame* frame, SubmapStore* store, KeyframeId* reference,
                                                  RelocalizationScope scope, size_t more_keyframes_than,
                                                  const std::set<KeyframeId>* only_at) {
  const Map* current = store->current();
  if (scope == RelocalizationScope::kCurrentSubmap && !current) return std::nullopt;
  if (wait_for_keyframe_bow_) wait_for_keyframe_bow_();  // every keyframe in the database
  ComputeBow(*vocabulary_, frame);
  const int64_t current_id = current ? current->id().value : -1;
  const bool in_current = scope == RelocalizationScope::kCurrentSubmap;
  const std::function<bool(int64_t)> accept = [&](int64_t submap) {
    if ((submap == current_id) != in_current) return false;
    if (scope == RelocalizationScope::kSavedMaps && !IsSavedMap(SubmapId(submap))) return false;
    if (in_current || more_keyframes_than == 0) return true;
    const Map* map = store->FindMap(SubmapId(submap));
    return map && map->num_keyframes() > more_keyframes_than;
  };
  std::vector<KeyframeDatabase::Candidate> candidates = store->database().Query(frame->bow, accept);
  if (only_at) {
    candidates.erase(std::remove_if(candidates.begin(), candidates.end(),
                                    [&](const auto& c) { return !only_at->count(KeyframeId(c.keyframe_id)); }),
                     candidates.end());
  }
  if (candidates.empty()) return std::nullopt;
  int most_common = 0;
  for (const auto& c : candidates) most_common = std::max(most_common, c.common_words);
  candidates.erase(std::remove_if(candidates.begin(), candidates.end(),
                                  [&](const auto& c) { return c.common_words < 0.8 * most_common; }),
                   candidates.end());
  std::sort(candidates.begin(), candidates.end(), [](const auto& a, const auto& b) { return a.score > b.score; });
  if (static_cast<int>(candidates.size()) > options_.relocalization_candidates) {
    candidates.resize(options_.relocalization_candidates);
  }
  for (const auto& candidate : candidates) {
    const KeyframeId id(candidate.keyframe_id);
    const Map* map = in_current ? current : store->FindMap(SubmapOf(id));
    if (map && RelocalizeAt(frame, *map, id, reference)) return id;
  }
  return std::nullopt;
}

bool Relocalizer::RelocalizeAt(Frame* frame, const Map& map, KeyframeId candidate, KeyframeId* reference) {
  const Keyframe* keyframe = map.FindKeyframe(candidate);
  if (!keyframe) return false;
  frame->points.assign(frame->size(), MapPointId());
  frame->outlier.assign(frame->size(), 0);
  const int matches = options_.reference_matching == "bow"
                          ? SearchByBow(*keyframe, frame, map, 0.75)
                          : SearchByIndex(*keyframe, frame, map, placer_->FrameIndex(*frame), 0.75);
  if (matches < 15 || !placer_->PoseFromMatches(map, frame)) return false;
  *reference = candidate;
  return placer_->TrackLocalMap(map, frame, options_.relocalization_min_inliers, reference);
}

}  // namespace stitch
