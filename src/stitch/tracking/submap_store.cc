#include "stitch/tracking/submap_store.h"

namespace stitch {

void SubmapStore::StartCurrent(std::unique_ptr<Map> map, uint32_t next_keyframe_index) {
  if (current_) CloseCurrent();
  current_ = std::move(map);
  next_keyframe_index_ = next_keyframe_index;
}

std::optional<SubmapId> SubmapStore::CloseCurrent() {
  if (!current_) return std::nullopt;
  const SubmapId id = current_->id();
  closed_.push_back({std::move(current_), next_keyframe_index_});
  return id;
}

bool SubmapStore::Reopen(SubmapId id) {
  for (auto it = closed_.begin(); it != closed_.end(); ++it) {
    if (it->map->id() != id) continue;
    if (current_) CloseCurrent();
    current_ = std::move(it->map);
    next_keyframe_index_ = it->next_keyframe_index;
    closed_.erase(it);
    return true;
  }
  return false;
}

KeyframeId SubmapStore::NewKeyframeId() { return MakeKeyframeId(current_->id(), next_keyframe_index_++); }

Keyframe* SubmapStore::FindKeyframe(KeyframeId id) {
  Map* map = FindMap(SubmapOf(id));
  return map ? map->FindKeyframe(id) : nullptr;
}

Map* SubmapStore::FindMap(SubmapId id) {
  if (current_ && current_->id() == id) return current_.get();
  for (Closed& closed : closed_) {
    if (closed.map->id() == id) return closed.map.get();
  }
  return nullptr;
}

bool SubmapStore::Apply(const LocalMapUpdate& update) {
  Map* target = FindMap(update.submap);
  if (!target) return false;
  ApplyLocalMapUpdate(update, target);
  for (KeyframeId id : update.removed_keyframes) database_.Remove(id.value);
  return true;
}

void SubmapStore::AddToDatabase(const Keyframe& keyframe) {
  database_.Add(keyframe.id.value, SubmapOf(keyframe.id).value, keyframe.bow);
}

}  // namespace stitch
