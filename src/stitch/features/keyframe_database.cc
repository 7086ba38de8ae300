#include "stitch/features/keyframe_database.h"

#include <algorithm>
#include <cmath>

namespace stitch {

void KeyframeDatabase::Add(int64_t keyframe_id, int64_t submap_id, const BowVector& bow) {
  Remove(keyframe_id);
  for (const auto& [word, weight] : bow.entries) inverted_[word].push_back({keyframe_id, weight});
  entries_[keyframe_id] = {submap_id, bow};
}

void KeyframeDatabase::Remove(int64_t keyframe_id) {
  const auto it = entries_.find(keyframe_id);
  if (it == entries_.end()) return;
  for (const auto& [word, weight] : it->second.bow.entries) {
    auto& postings = inverted_[word];
    postings.erase(std::remove_if(postings.begin(), postings.end(),
                                  [&](const Posting& p) { return p.keyframe_id == keyframe_id; }),
                   postings.end());
    if (postings.empty()) inverted_.erase(word);
  }
  entries_.erase(it);
}

void KeyframeDatabase::Clear() {
  entries_.clear();
  inverted_.clear();
}

const BowVector* KeyframeDatabase::Find(int64_t keyframe_id) const {
  const auto it = entries_.find(keyframe_id);
  return it == entries_.end() ? nullptr : &it->second.bow;
}

std::vector<KeyframeDatabase::Candidate> KeyframeDatabase::Query(const BowVector& query,
                                                                 const std::function<bool(int64_t)>& accept_submap,
                                                                 int min_common_words) const {
  // One pass over the query's postings accumulates, per keyframe, the shared words and the shared
  // part of the L1 score (|q| + |k| - |q - k| per shared word).
  struct Tally {
    int common = 0;
    double shared = 0;
  };
  std::unordered_map<int64_t, Tally> tallies;
  std::unordered_map<int64_t, bool> accepted;
  for (const auto& [word, query_weight] : query.entries) {
    const auto postings = inverted_.find(word);
    if (postings == inverted_.end()) continue;
    for (const Posting& p : postings->second) {
      if (accept_submap) {
        auto known = accepted.find(p.keyframe_id);
        if (known == accepted.end()) {
          known = accepted.emplace(p.keyframe_id, accept_submap(entries_.at(p.keyframe_id).submap_id)).first;
        }
        if (!known->second) continue;
      }
      Tally& t = tallies[p.keyframe_id];
      ++t.common;
      t.shared += std::abs(query_weight) + std::abs(p.weight) - std::abs(query_weight - p.weight);
    }
  }
  std::vector<Candidate> candidates;
  candidates.reserve(tallies.size());
  for (const auto& [keyframe_id, t] : tallies) {
    if (t.common < min_common_words) continue;
    candidates.push_back({keyframe_id, entries_.at(keyframe_id).submap_id, t.common, 0.5 * t.shared});
  }
  return candidates;
}

}  // namespace stitch
