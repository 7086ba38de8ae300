#pragma once
// A set of nonzero 64-bit ids for per-frame bookkeeping (which map points were seen): open
// addressing with linear probing, cleared in O(1) by bumping a generation, so the table is
// allocated once and reused frame after frame. Insert() returns whether the id was new.

#include <cstddef>
#include <cstdint>
#include <vector>

namespace stitch {

class FlatIdSet {
 public:
  // Empties the set and makes room for `expected` ids without growing.
  void Clear(size_t expected = 0) {
    size_t capacity = slots_.empty() ? 1024 : slots_.size();
    while (capacity < 2 * expected) capacity *= 2;
    if (capacity != slots_.size() || ++generation_ == 0) {
      slots_.assign(capacity, Slot{});
      generation_ = 1;
    }
    size_ = 0;
  }

  bool Insert(uint64_t id) {
    if (slots_.empty() || 2 * (size_ + 1) > slots_.size()) Grow();
    for (size_t i = Hash(id) & (slots_.size() - 1);; i = (i + 1) & (slots_.size() - 1)) {
      Slot& slot = slots_[i];
      if (slot.generation != generation_) {
        slot = {id, generation_};
        ++size_;
        return true;
      }
      if (slot.id == id) return false;
    }
  }

  bool Contains(uint64_t id) const {
    if (slots_.empty()) return false;
    for (size_t i = Hash(id) & (slots_.size() - 1);; i = (i + 1) & (slots_.size() - 1)) {
      const Slot& slot = slots_[i];
      if (slot.generation != generation_) return false;
      if (slot.id == id) return true;
    }
  }

  size_t size() const { return size_; }

 private:
  struct Slot {
    uint64_t id = 0;
    uint32_t generation = 0;
  };
  static size_t Hash(uint64_t id) {
    id ^= id >> 33;
    id *= 0xff51afd7ed558ccdULL;
    id ^= id >> 33;
    return static_cast<size_t>(id);
  }
  void Grow() {
    std::vector<Slot> old;
    old.swap(slots_);
    const uint32_t old_generation = generation_;
    slots_.assign(old.empty() ? 1024 : 2 * old.size(), Slot{});
    generation_ = 1;
    size_ = 0;
    for (const Slot& slot : old) {
      if (slot.generation == old_generation) Insert(slot.id);
    }
  }

  std::vector<Slot> slots_;
  uint32_t generation_ = 1;
  size_t size_ = 0;
};

}  // namespace stitch
