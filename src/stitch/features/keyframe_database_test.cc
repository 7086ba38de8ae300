#include "stitch/features/keyframe_database.h"

#include <gtest/gtest.h>

#include "stitch/features/vocabulary.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

// A strip of keyframes over a row of 1200 landmarks: keyframe i sees landmarks [10 i, 10 i + 100),
// so neighbours share 90%, keyframes 5 apart 50%, 10 or more apart nothing. Known overlaps.
struct Strip {
  std::vector<Descriptor> landmarks;
  std::vector<cv::Mat> keyframes;
};

Strip MakeStrip(int num_keyframes) {
  Rng rng(11);
  Strip strip;
  for (int i = 0; i < 10 * num_keyframes + 100; ++i) {
    Descriptor d;
    for (auto& b : d) b = static_cast<uint8_t>(rng.NextU64());
    strip.landmarks.push_back(d);
  }
  for (int k = 0; k < num_keyframes; ++k) {
    cv::Mat m(100, 32, CV_8U);
    for (int j = 0; j < 100; ++j) {
      Descriptor d = strip.landmarks[10 * k + j];
      for (int f = 0; f < 6; ++f) {
        const int bit = static_cast<int>(rng.NextU64() % 256);
        d[bit / 8] ^= static_cast<uint8_t>(1u << (bit % 8));
      }
      std::memcpy(m.ptr(j), d.data(), 32);
    }
    strip.keyframes.push_back(m);
  }
  return strip;
}

Vocabulary TrainOn(const Strip& strip) {
  std::vector<std::vector<Descriptor>> images;
  for (const auto& m : strip.keyframes) {
    std::vector<Descriptor> image;
    for (int i = 0; i < m.rows; ++i) image.push_back(ToDescriptor(m.ptr(i)));
    images.push_back(image);
  }
  VocabularyTrainingOptions options;
  options.branching = 8;
  options.depth = 3;
  return Vocabulary::Train(images, options);
}

TEST(KeyframeDatabase, ReturnsTheTrueNeighbourFirst) {
  const Strip strip = MakeStrip(100);
  const Vocabulary vocabulary = TrainOn(strip);
  KeyframeDatabase database;
  std::vector<BowVector> bows;
  for (int k = 0; k < 100; ++k) {
    bows.push_back(vocabulary.Transform(strip.keyframes[k]));
    database.Add(k, k < 50 ? 1 : 2, bows.back());
  }
  int correct = 0;
  for (int q = 1; q < 99; ++q) {
    auto candidates = database.Query(bows[q], [](int64_t) { return true; });
    std::sort(candidates.begin(), candidates.end(), [](const auto& a, const auto& b) { return a.score > b.score; });
    ASSERT_GE(candidates.size(), 3u);
    EXPECT_EQ(candidates[0].keyframe_id, q);  // itself
    const int64_t best_other = candidates[1].keyframe_id;
    correct += best_other == q - 1 || best_other == q + 1;
    // Every candidate's counts agree with the direct computation.
    for (const auto& c : candidates) {
      ASSERT_EQ(c.common_words, CommonWords(bows[q], bows[c.keyframe_id]));
      ASSERT_NEAR(c.score, ScoreL1(bows[q], bows[c.keyframe_id]), 1e-5);
    }
    // Scores fall with the overlap.
    const auto score_of = [&](int64_t id) {
      for (const auto& c : candidates) {
        if (c.keyframe_id == id) return c.score;
      }
      return 0.0;
    };
    if (q >= 10) {
      EXPECT_GT(score_of(q - 1), score_of(q - 5));
    }
  }
  EXPECT_GE(correct, 95);
}

TEST(KeyframeDatabase, FiltersBySubmapAndForgetsRemovedKeyframes) {
  const Strip strip = MakeStrip(40);
  const Vocabulary vocabulary = TrainOn(strip);
  KeyframeDatabase database;
  for (int k = 0; k < 40; ++k) database.Add(k, k < 20 ? 1 : 2, vocabulary.Transform(strip.keyframes[k]));
  const BowVector query = vocabulary.Transform(strip.keyframes[19]);
  const auto others = database.Query(query, [](int64_t submap) { return submap != 1; });
  ASSERT_FALSE(others.empty());
  for (const auto& c : others) EXPECT_EQ(c.submap_id, 2);
  // Keyframe 20 (submap 2) overlaps 19 by 90%: it is the best of the other submap.
  const auto best =
      std::max_element(others.begin(), others.end(), [](const auto& a, const auto& b) { return a.score < b.score; });
  EXPECT_EQ(best->keyframe_id, 20);
  database.Remove(20);
  EXPECT_FALSE(database.Contains(20));
  for (const auto& c : database.Query(query)) EXPECT_NE(c.keyframe_id, 20);
  EXPECT_EQ(database.size(), 39u);
}

}  // namespace
}  // namespace stitch
