#pragma once
// Relocalization: a frame placed from scratch in a submap. The keyframe database proposes the
// keyframes sharing the most words with the frame (at least 0.8 of the best count, best scores
// first, at most options.relocalization_candidates); each is matched (bag of words or a
// descriptor index), a PnP RANSAC pose is optimized, and the local map must confirm it with
// options.relocalization_min_inliers points. One owner thread; not thread-safe.

#include <functional>
#include <optional>
#include <set>

#include "stitch/features/vocabulary.h"
#include "stitch/tracking/frame_placer.h"
#include "stitch/tracking/submap_store.h"
#include "stitch/tracking/tracking_options.h"

namespace stitch {

// Where a frame is relocalized: in the current submap (the relocalize policy, or a camera lost in
// it), in the closed submaps and saved maps (a new submap initializing or still young), or in
// the saved maps only (a flight's first frames, stitch run --map).
enum class RelocalizationScope { kCurrentSubmap, kClosedSubmaps, kSavedMaps };

class Relocalizer {
 public:
  // `placer` and `vocabulary` must outlive the relocalizer. `wait_for_keyframe_bow` (optional)
  // brings every keyframe's bag of words into the database before a query.
  Relocalizer(const TrackingOptions& options, FramePlacer* placer, const Vocabulary* vocabulary,
              std::function<void()> wait_for_keyframe_bow = nullptr);

  // Places `frame` in the store's current submap, or in any closed one (by `scope`). Returns the
  // keyframe it was relocalized at (its submap is where the frame is); `reference` becomes the
  // keyframe sharing most points with the frame. Each candidate tried may change `reference`
  // even when none succeeds. In closed submaps, only those with more than `more_keyframes_than`.
  // `only_at` (optional): the keyframes a relocalization may land at; candidates elsewhere are
  // not tried.
  std::optional<KeyframeId> Relocalize(Frame* frame, SubmapStore* store, KeyframeId* reference,
                                       RelocalizationScope scope, size_t more_keyframes_than = 0,
                                       const std::set<KeyframeId>* only_at = nullptr);

 private:
  bool RelocalizeAt(Frame* frame, const Map& map, KeyframeId candidate, KeyframeId* reference);

  TrackingOptions options_;
  FramePlacer* placer_;
  const Vocabulary* vocabulary_;
  std::function<void()> wait_for_keyframe_bow_;
};

}  // namespace stitch
