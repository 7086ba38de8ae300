#pragma once
// Nearest neighbours among a set of binary descriptors, without a pose to guide the search:
// brute force (every descriptor compared) or a locality-sensitive hashing index (our own: several
// tables, each keyed by a fixed sample of the 256 bits, so descriptors a few dozen bits apart
// still share a key in some table; optionally also probed at every key one bit away). The index
// shares the descriptor matrix it was built on (cv::Mat's reference count keeps it). Queries reuse
// scratch space: one thread at a time.

#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "stitch/features/descriptor.h"

namespace stitch {

enum class DescriptorSearch { kBruteForce, kLsh };
// "brute_force" or "lsh"; throws stitch::Error for anything else.
DescriptorSearch ParseDescriptorSearch(const std::string& name);

// Defaults from build/bin/matching_benchmark: 12 tables of 10 bits find the same matches as
// brute force between a keyframe and a frame, 5x faster; probing the buckets one bit away as
// well costs 2.5x and finds no more there (it helps descriptors 40-60 bits apart).
struct LshOptions {
  int tables = 12;                // hash tables; more find more far neighbours and cost more per query
  int key_bits = 10;              // bits per key (1024 buckets a table)
  bool probe_neighbours = false;  // also the buckets one bit away from the query's key
  uint64_t seed = 1;              // which bits each table samples
};

struct NearestDescriptors {
  int best = -1;  // row, or -1 when no usable row was examined
  int best_distance = 256;
  int second_distance = 256;
};

class DescriptorIndex {
 public:
  // `descriptors`: N x 32 CV_8U.
  DescriptorIndex(const cv::Mat& descriptors, DescriptorSearch search, const LshOptions& lsh = {});

  // Best and second best among the rows for which `usable(row)` holds (the LSH index examines
  // only the rows that share a bucket with the query, so it may miss the true best).
  template <class Usable>
  NearestDescriptors Nearest(const uint8_t* query, Usable usable) const;
  NearestDescriptors Nearest(const uint8_t* query) const {
    return Nearest(query, [](int) { return true; });
  }

  DescriptorSearch search() const { return search_; }
  int size() const { return descriptors_.rows; }

 private:
  uint32_t Key(const uint8_t* descriptor, int table) const;
  // Calls visit(row) once for every row sharing a probed bucket with `query`.
  template <class Visit>
  void ForEachCandidate(const uint8_t* query, Visit visit) const;

  cv::Mat descriptors_;
  DescriptorSearch search_;
  LshOptions lsh_;
  std::vector<std::vector<uint16_t>> sampled_bits_;  // per table: which of the 256 bits
  std::vector<std::vector<int>> bucket_start_;       // per table: 2^key_bits + 1 offsets into rows
  std::vector<std::vector<int>> bucket_rows_;        // per table: rows sorted by key
  mutable std::vector<uint32_t> seen_;               // per row: the query number that last saw it
  mutable uint32_t query_number_ = 0;
};

template <class Usable>
NearestDescriptors DescriptorIndex::Nearest(const uint8_t* query, Usable usable) const {
  NearestDescriptors result;
  const auto consider = [&](int row) {
    if (!usable(row)) return;
    const int d = HammingDistance(query, descriptors_.ptr<uint8_t>(row));
    if (d < result.best_distance) {
      result.second_distance = result.best_distance;
      result.best_distance = d;
      result.best = row;
    } else if (d < result.second_distance) {
      result.second_distance = d;
    }
  };
  if (search_ == DescriptorSearch::kBruteForce) {
    for (int row = 0; row < descriptors_.rows; ++row) consider(row);
  } else {
    ForEachCandidate(query, consider);
  }
  return result;
}

template <class Visit>
void DescriptorIndex::ForEachCandidate(const uint8_t* query, Visit visit) const {
  if (++query_number_ == 0) {
    std::fill(seen_.begin(), seen_.end(), 0);
    query_number_ = 1;
  }
  const int flips = lsh_.probe_neighbours ? lsh_.key_bits : 0;
  for (int t = 0; t < lsh_.tables; ++t) {
    const uint32_t key = Key(query, t);
    const int* start = bucket_start_[t].data();
    const int* rows = bucket_rows_[t].data();
    // The query's bucket, then those one bit away.
    for (int flip = -1; flip < flips; ++flip) {
      const uint32_t probe = flip < 0 ? key : key ^ (1u << flip);
      for (int i = start[probe]; i < start[probe + 1]; ++i) {
        const int row = rows[i];
        if (seen_[row] == query_number_) continue;
        seen_[row] = query_number_;
        visit(row);
      }
    }
  }
}

}  // namespace stitch
