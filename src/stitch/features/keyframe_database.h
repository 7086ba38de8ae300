#pragma once
// An inverted index from words to the keyframes that contain them, for place recognition,
// relocalization and the merger's connected-frame retrieval. Keyframes carry their submap so a
// query can look only at other submaps (or only at one). Not thread-safe: one owner.

#include <cstdint>
#include <functional>
#include <unordered_map>
#include <vector>

#include "stitch/features/bow.h"

namespace stitch {

class KeyframeDatabase {
 public:
  struct Candidate {
    int64_t keyframe_id = -1;
    int64_t submap_id = -1;
    int common_words = 0;  // words shared with the query
    double score = 0;      // L1 score with the query
  };

  // Adds (or replaces) a keyframe.
  void Add(int64_t keyframe_id, int64_t submap_id, const BowVector& bow);
  void Remove(int64_t keyframe_id);
  void Clear();
  size_t size() const { return entries_.size(); }
  bool Contains(int64_t keyframe_id) const { return entries_.count(keyframe_id) > 0; }
  const BowVector* Find(int64_t keyframe_id) const;

  // Every keyframe that shares at least `min_common_words` words with `query` and whose submap
  // `accept_submap` accepts (all when empty), with its common-word count and L1 score, in no
  // particular order. What the adaptive thresholds of docs/method.md need.
  std::vector<Candidate> Query(const BowVector& query, const std::function<bool(int64_t)>& accept_submap = nullptr,
                               int min_common_words = 1) const;

 private:
  struct Entry {
    int64_t submap_id;
    BowVector bow;
  };
  struct Posting {
    int64_t keyframe_id;
    float weight;
  };
  std::unordered_map<int64_t, Entry> entries_;
  std::unordered_map<WordId, std::vector<Posting>> inverted_;
};

}  // namespace stitch
