#include "stitch/tracking/submap_store.h"

#include <algorithm>

namespace stitch {

void SubmapStore::StartCurrent(std::unique_ptr<Map> map, uint32_t next_keyframe_index) {
  if (current_) CloseCurrent();
  current_ = std::move(map);
  next_keyframe_index_ = next_keyframe_index;
}

std::optional<SubmapId> SubmapStore::CloseCurrent() {
  if (!current_) return std::nullopt;
  if (IsSavedMap(current_->id())) {
    saved_.push_back(std::move(current_));
    return std::nullopt;
  }
  const SubmapId id = current_->id();
  closed_.push_back({std::move(current_), next_keyframe_index_});
  return id;
}

bool SubmapStore::Reopen(SubmapId id) {
  const auto it = std::find_if(closed_.begin(), closed_.end(), [&](const Closed& c) { return c.map->id() == id; });
  if (it == closed_.end()) return false;
  Closed reopened = std::move(*it);
  closed_.erase(it);
  if (current_) CloseCurrent();
  current_ = std::move(reopened.map);
  next_keyframe_index_ = reopened.next_keyframe_index;
  return true;
}

std::vector<SubmapId> SubmapStore::DropClosedBeyond(size_t max_keyframes, bool keep_last) {
  size_t held = 0;
  for (const Closed& closed : closed_) held += closed.map->num_keyframes();
  std::vector<SubmapId> dropped;
  while (closed_.size() > (keep_last ? 1u : 0u) && held > max_keyframes) {
    const Map& oldest = *closed_.front().map;
    held -= oldest.num_keyframes();
    for (const auto& [id, keyframe] : oldest.keyframes()) database_.Remove(id.value);
    dropped.push_back(oldest.id());
    closed_.erase(closed_.begin());
  }
  return dropped;
}

int SubmapStore::LowestNumberHeld(int otherwise) const {
  int lowest = current_ ? SubmapNumber(current_->id()) : otherwise;
  for (const Closed& closed : closed_) lowest = std::min(lowest, SubmapNumber(closed.map->id()));
  return lowest;
}

KeyframeId SubmapStore::NewKeyframeId() {
  return MakeKeyframeId(current_->id(), next_keyframe_index_++);
}

Keyframe* SubmapStore::FindKeyframe(KeyframeId id) {
  Map* map = FindMap(SubmapOf(id));
  return map ? map->FindKeyframe(id) : nullptr;
}

Map* SubmapStore::FindMap(SubmapId id) {
  if (current_ && current_->id() == id) return current_.get();
  for (Closed& closed : closed_) {
    if (closed.map->id() == id) return closed.map.get();
  }
  for (const std::unique_ptr<Map>& saved : saved_) {
    if (saved->id() == id) return saved.get();
  }
  return nullptr;
}

bool SubmapStore::MakeSavedCurrent(SubmapId id) {
  const auto it =
      std::find_if(saved_.begin(), saved_.end(), [&](const std::unique_ptr<Map>& m) { return m->id() == id; });
  if (it == saved_.end()) return false;
  std::unique_ptr<Map> map = std::move(*it);
  saved_.erase(it);
  if (current_) CloseCurrent();
  current_ = std::move(map);
  next_keyframe_index_ = 0;  // never used: no keyframe is added to a saved map
  return true;
}

void SubmapStore::AddSaved(std::unique_ptr<Map> map) {
  for (const auto& [id, keyframe] : map->keyframes()) AddToDatabase(keyframe);
  saved_.push_back(std::move(map));
}

bool SubmapStore::Apply(const LocalMapUpdate& update) {
  Map* target = IsSavedMap(update.submap) ? nullptr : FindMap(update.submap);
  if (!target) return false;
  ApplyLocalMapUpdate(update, target);
  for (KeyframeId id : update.removed_keyframes) database_.Remove(id.value);
  return true;
}

void SubmapStore::AddToDatabase(const Keyframe& keyframe) {
  database_.Add(keyframe.id.value, SubmapOf(keyframe.id).value, keyframe.bow);
}

}  // namespace stitch
