#include "stitch/features/bow.h"

#include <cmath>

namespace stitch {

double ScoreL1(const BowVector& a, const BowVector& b) {
  // For L1-normalized vectors: |a - b|_1 = 2 - sum over shared words of (|a_i| + |b_i| - |a_i - b_i|).
  double shared = 0;
  auto i = a.entries.begin(), j = b.entries.begin();
  while (i != a.entries.end() && j != b.entries.end()) {
    if (i->first < j->first) {
      ++i;
    } else if (j->first < i->first) {
      ++j;
    } else {
      shared += std::abs(i->second) + std::abs(j->second) - std::abs(i->second - j->second);
      ++i;
      ++j;
    }
  }
  return 0.5 * shared;
}

int CommonWords(const BowVector& a, const BowVector& b) {
  int common = 0;
  auto i = a.entries.begin(), j = b.entries.begin();
  while (i != a.entries.end() && j != b.entries.end()) {
    if (i->first < j->first) {
      ++i;
    } else if (j->first < i->first) {
      ++j;
    } else {
      ++common;
      ++i;
      ++j;
    }
  }
  return common;
}

}  // namespace stitch
