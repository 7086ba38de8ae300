#include "stitch/features/descriptor_index.h"

#include <gtest/gtest.h>

#include "stitch/features/orb_extractor.h"
#include "stitch/synthetic/synthetic_sequence.h"
#include "stitch/util/error.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

cv::Mat RandomDescriptors(int rows, Rng* rng) {
  cv::Mat d(rows, kDescriptorBytes, CV_8U);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < kDescriptorBytes; ++c) d.at<uint8_t>(r, c) = static_cast<uint8_t>(rng->UniformInt(0, 255));
  }
  return d;
}

// Row `row` of `d` with `flips` distinct bits flipped.
Descriptor Flipped(const cv::Mat& d, int row, int flips, Rng* rng) {
  Descriptor q = ToDescriptor(d.ptr<uint8_t>(row));
  std::vector<int> bits(256);
  for (int i = 0; i < 256; ++i) bits[i] = i;
  for (int i = 0; i < flips; ++i) {
    std::swap(bits[i], bits[i + rng->UniformInt(0, 255 - i)]);
    q[bits[i] / 8] ^= static_cast<uint8_t>(1u << (bits[i] % 8));
  }
  return q;
}

TEST(DescriptorIndex, BruteForceAndLshFindTheSourceOfANoisyCopy) {
  Rng rng(3);
  const cv::Mat d = RandomDescriptors(1000, &rng);
  LshOptions probing;
  probing.probe_neighbours = true;
  probing.tables = 6;
  const DescriptorIndex brute(d, DescriptorSearch::kBruteForce), lsh(d, DescriptorSearch::kLsh),
      lsh_probing(d, DescriptorSearch::kLsh, probing);
  for (int flips : {0, 10, 30, 50}) {
    int probing_found = 0;
    int brute_found = 0, lsh_found = 0;
    const int queries = 400;
    for (int q = 0; q < queries; ++q) {
      const int row = rng.UniformInt(0, d.rows - 1);
      const Descriptor query = Flipped(d, row, flips, &rng);
      const NearestDescriptors b = brute.Nearest(query.data()), l = lsh.Nearest(query.data());
      brute_found += b.best == row && b.best_distance == flips;
      probing_found += lsh_probing.Nearest(query.data()).best == row;
      if (l.best == row) {
        ++lsh_found;
        EXPECT_EQ(l.best_distance, flips);
      }
    }
    EXPECT_EQ(brute_found, queries) << flips << " bits flipped";
    // Expected recall of 12 tables of 10 bits: 1 - (1 - (1 - flips/256)^10)^12 = 1.0, 1.0, 0.983, 0.766.
    const double expected = flips <= 10 ? 0.99 : flips <= 30 ? 0.95 : 0.65;
    EXPECT_GE(lsh_found, expected * queries) << flips << " bits flipped";
    // 6 tables probed at distance <= 1 from the key: 1.0, 1.0, 0.999, 0.947.
    EXPECT_GE(probing_found, (flips <= 30 ? 0.98 : 0.88) * queries) << flips << " bits flipped, probing";
  }
}

TEST(DescriptorIndex, OnlyUsableRowsAreConsidered) {
  Rng rng(4);
  const cv::Mat d = RandomDescriptors(300, &rng);
  for (DescriptorSearch search : {DescriptorSearch::kBruteForce, DescriptorSearch::kLsh}) {
    const DescriptorIndex index(d, search);
    const NearestDescriptors excluded = index.Nearest(d.ptr<uint8_t>(7), [](int row) { return row != 7; });
    EXPECT_NE(excluded.best, 7);
    EXPECT_GT(excluded.best_distance, 0);
    const NearestDescriptors none = index.Nearest(d.ptr<uint8_t>(7), [](int) { return false; });
    EXPECT_EQ(none.best, -1);
    EXPECT_EQ(none.best_distance, 256);
  }
  const DescriptorIndex empty(cv::Mat(0, 32, CV_8U), DescriptorSearch::kLsh);
  EXPECT_EQ(empty.Nearest(d.ptr<uint8_t>(0)).best, -1);
  EXPECT_THROW(DescriptorIndex(cv::Mat(5, 16, CV_8U), DescriptorSearch::kLsh), Error);
  EXPECT_THROW(ParseDescriptorSearch("kd_tree"), Error);
  EXPECT_EQ(ParseDescriptorSearch("lsh"), DescriptorSearch::kLsh);
  EXPECT_EQ(ParseDescriptorSearch("brute_force"), DescriptorSearch::kBruteForce);
}

TEST(DescriptorIndex, LshFindsNearlyAllOfBruteForcesMatchesBetweenConsecutiveFrames) {
  SyntheticOptions options;
  options.flight.num_frames = 100;
  options.flight.num_strips = 1;
  options.flight.strip_length_m = 100;
  const SyntheticSequence sequence(options, FailureSchedule());
  OrbExtractor extractor{OrbOptions{}};
  std::vector<cv::KeyPoint> ka, kb;
  cv::Mat da, db;
  extractor.Extract(sequence.RenderFrame(30), &ka, &da);
  extractor.Extract(sequence.RenderFrame(33), &kb, &db);
  const DescriptorIndex brute(db, DescriptorSearch::kBruteForce), lsh(db, DescriptorSearch::kLsh);
  int brute_matches = 0, lsh_matches = 0, agree = 0;
  const auto accepted = [](const NearestDescriptors& n) {
    return n.best >= 0 && n.best_distance <= kDescriptorDistanceLow && n.best_distance < 0.8 * n.second_distance;
  };
  for (int i = 0; i < da.rows; ++i) {
    const NearestDescriptors b = brute.Nearest(da.ptr<uint8_t>(i)), l = lsh.Nearest(da.ptr<uint8_t>(i));
    brute_matches += accepted(b);
    lsh_matches += accepted(l);
    agree += accepted(b) && accepted(l) && b.best == l.best;
  }
  EXPECT_GT(brute_matches, 300);
  EXPECT_GE(agree, 0.9 * brute_matches);
  EXPECT_LE(lsh_matches, brute_matches * 1.05);  // LSH sees fewer second-best rows: a few more pass the ratio
}

}  // namespace
}  // namespace stitch
