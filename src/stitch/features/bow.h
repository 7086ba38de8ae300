#pragma once
// Bag-of-words vectors: sparse, sorted by word id.

#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

namespace stitch {

using WordId = uint32_t;
using NodeId = uint32_t;

// (word, weight) sorted by word, weights L1-normalized by the vocabulary's Transform.
struct BowVector {
  std::vector<std::pair<WordId, float>> entries;
  bool empty() const { return entries.empty(); }
  size_t size() const { return entries.size(); }
};

// Direct index: for each vocabulary node at a chosen level, the features that fall under it,
// sorted by node. Two frames need only compare features under the same node.
struct FeatureVector {
  std::vector<std::pair<NodeId, std::vector<int>>> nodes;
};

// L1 score of two normalized vectors: 1 - |a - b|_1 / 2, in [0, 1]; 1 for identical vectors.
double ScoreL1(const BowVector& a, const BowVector& b);
// Number of words the two vectors share.
int CommonWords(const BowVector& a, const BowVector& b);

}  // namespace stitch
