#include "stitch/features/descriptor_index.h"

#include <algorithm>
#include <numeric>

#include "stitch/util/error.h"
#include "stitch/util/rng.h"

namespace stitch {

DescriptorSearch ParseDescriptorSearch(const std::string& name) {
  if (name == "brute_force") return DescriptorSearch::kBruteForce;
  if (name == "lsh") return DescriptorSearch::kLsh;
  throw Error("descriptor search must be brute_force or lsh, not '" + name + "'");
}

DescriptorIndex::DescriptorIndex(const cv::Mat& descriptors, DescriptorSearch search, const LshOptions& lsh)
    : descriptors_(descriptors), search_(search), lsh_(lsh) {
  if (!descriptors_.empty() && (descriptors_.type() != CV_8U || descriptors_.cols != kDescriptorBytes)) {
    throw Error("DescriptorIndex: descriptors must be N x 32 CV_8U");
  }
  if (search_ != DescriptorSearch::kLsh) return;
  if (lsh_.tables < 1 || lsh_.tables > 64 || lsh_.key_bits < 4 || lsh_.key_bits > 16) {
    throw Error("DescriptorIndex: LSH needs 1-64 tables of 4-16 key bits");
  }
  // Each table samples its own bits, without repetition inside a table.
  Rng rng(lsh_.seed);
  std::vector<uint16_t> all(kDescriptorBytes * 8);
  std::iota(all.begin(), all.end(), 0);
  const int buckets = 1 << lsh_.key_bits;
  const int rows = descriptors_.rows;
  sampled_bits_.resize(lsh_.tables);
  bucket_start_.resize(lsh_.tables);
  bucket_rows_.resize(lsh_.tables);
  std::vector<uint32_t> keys(rows);
  for (int t = 0; t < lsh_.tables; ++t) {
    for (int i = 0; i < lsh_.key_bits; ++i)
      std::swap(all[i], all[i + rng.UniformInt(0, static_cast<int>(all.size()) - 1 - i)]);
    sampled_bits_[t].assign(all.begin(), all.begin() + lsh_.key_bits);
    // Counting sort of the rows by key: bucket b holds rows [start[b], start[b + 1]).
    std::vector<int>& start = bucket_start_[t];
    start.assign(buckets + 1, 0);
    for (int r = 0; r < rows; ++r) {
      keys[r] = Key(descriptors_.ptr<uint8_t>(r), t);
      ++start[keys[r] + 1];
    }
    for (int b = 0; b < buckets; ++b) start[b + 1] += start[b];
    std::vector<int> fill(start.begin(), start.end() - 1);
    bucket_rows_[t].resize(rows);
    for (int r = 0; r < rows; ++r) bucket_rows_[t][fill[keys[r]]++] = r;
  }
  seen_.assign(rows, 0);
}

uint32_t DescriptorIndex::Key(const uint8_t* descriptor, int table) const {
  uint32_t key = 0;
  for (uint16_t bit : sampled_bits_[table]) key = (key << 1) | ((descriptor[bit >> 3] >> (bit & 7)) & 1u);
  return key;
}

}  // namespace stitch
