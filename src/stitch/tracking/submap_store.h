#pragma once
// The tracker's submaps: the current one (the camera is tracked in it; empty while a new map
// initializes), the closed ones (kept for relocalization, and refined by the mapper's updates
// as long as it sends them), and the keyframe database over all of them. Owned by Tracking's
// thread; not thread-safe.

#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include "stitch/features/keyframe_database.h"
#include "stitch/map/local_map_update.h"
#include "stitch/map/map.h"

namespace stitch {

class SubmapStore {
 public:
  // The current submap, or null.
  Map* current() const { return current_.get(); }
  // `map` becomes the current submap; its next keyframe gets index `next_keyframe_index`.
  void StartCurrent(std::unique_ptr<Map> map, uint32_t next_keyframe_index);
  // The current submap goes among the closed ones (with its keyframe numbering); its id.
  std::optional<SubmapId> CloseCurrent();
  // A closed submap becomes the current one again; false when there is no such closed submap.
  bool Reopen(SubmapId id);
  bool has_closed() const { return !closed_.empty(); }
  // A saved map (stitch run --map, kSavedMapAgent): held for relocalization, never current,
  // dropped or refined; its keyframes must carry their bags of words (they enter the database).
  void AddSaved(std::unique_ptr<Map> map);
  bool has_saved() const { return !saved_.empty(); }
  // Localization only (tracker.tracking.localize_only): the saved map becomes the current one,
  // tracked in but never added to; false when there is no such saved map. Closing it (CloseCurrent)
  // puts it back among the saved maps and returns nothing: it is no submap of this flight.
  bool MakeSavedCurrent(SubmapId id);
  // Drops closed submaps, the longest closed first, while the closed ones hold more than
  // `max_keyframes` keyframes; with `keep_last`, the last closed one stays whatever its size.
  // Returns the ids dropped.
  std::vector<SubmapId> DropClosedBeyond(size_t max_keyframes, bool keep_last);
  // The lowest submap number among those held (current and closed), or `otherwise` when none.
  int LowestNumberHeld(int otherwise) const;

  // The id of the current submap's next keyframe (which it numbers in order).
  KeyframeId NewKeyframeId();
  // A keyframe of the current or a closed submap.
  Keyframe* FindKeyframe(KeyframeId id);
  // The current submap, a closed one or a saved map with this id.
  Map* FindMap(SubmapId id);
  // Applies the mapper's update to the submap it is for (current or closed); false when the
  // store has no such submap.
  bool Apply(const LocalMapUpdate& update);

  // Keyframes of every submap with their bags of words, for relocalization.
  const KeyframeDatabase& database() const { return database_; }
  void AddToDatabase(const Keyframe& keyframe);

 private:
  struct Closed {
    std::unique_ptr<Map> map;
    uint32_t next_keyframe_index = 0;
  };
  std::unique_ptr<Map> current_;
  uint32_t next_keyframe_index_ = 0;
  std::vector<Closed> closed_;
  std::vector<std::unique_ptr<Map>> saved_;
  KeyframeDatabase database_;
};

}  // namespace stitch
