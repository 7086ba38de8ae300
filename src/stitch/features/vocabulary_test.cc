#include "stitch/features/vocabulary.h"

#include <fstream>

#include <gtest/gtest.h>

#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

Descriptor RandomDescriptor(Rng* rng) {
  Descriptor d;
  for (auto& b : d) b = static_cast<uint8_t>(rng->NextU64());
  return d;
}

// A copy of `base` with `flips` random bits flipped.
Descriptor Noisy(const Descriptor& base, int flips, Rng* rng) {
  Descriptor d = base;
  for (int i = 0; i < flips; ++i) {
    const int bit = static_cast<int>(rng->NextU64() % 256);
    d[bit / 8] ^= static_cast<uint8_t>(1u << (bit % 8));
  }
  return d;
}

// Training images drawn from 300 "landmark" descriptors, 8 bits of noise per observation.
struct TrainingSet {
  std::vector<Descriptor> landmarks;
  std::vector<std::vector<Descriptor>> images;
};

TrainingSet MakeTrainingSet(int num_images = 60) {
  Rng rng(3);
  TrainingSet set;
  for (int i = 0; i < 300; ++i) set.landmarks.push_back(RandomDescriptor(&rng));
  for (int image = 0; image < num_images; ++image) {
    std::vector<Descriptor> descriptors;
    for (int k = 0; k < 200; ++k) descriptors.push_back(Noisy(set.landmarks[rng.NextU64() % 300], 8, &rng));
    set.images.push_back(descriptors);
  }
  return set;
}

cv::Mat ToMat(const std::vector<Descriptor>& descriptors) {
  cv::Mat m(static_cast<int>(descriptors.size()), 32, CV_8U);
  for (size_t i = 0; i < descriptors.size(); ++i) std::memcpy(m.ptr(static_cast<int>(i)), descriptors[i].data(), 32);
  return m;
}

VocabularyTrainingOptions SmallTree() {
  VocabularyTrainingOptions options;
  options.branching = 6;
  options.depth = 3;
  return options;
}

// An independent greedy descent through the public node list.
WordId DescendByHand(const Vocabulary& v, const Descriptor& d) {
  NodeId node = 0;
  while (v.node(node).num_children > 0) {
    NodeId best = 0;
    int best_distance = 1000;
    for (int c = 0; c < v.node(node).num_children; ++c) {
      const NodeId child = v.node(node).first_child + c;
      const int distance = HammingDistance(d, v.node(child).descriptor);
      if (distance < best_distance) {
        best_distance = distance;
        best = child;
      }
    }
    node = best;
  }
  return static_cast<WordId>(v.node(node).word);
}

TEST(Vocabulary, TrainsATreeOfTheRequestedShape) {
  const TrainingSet set = MakeTrainingSet();
  double last_progress = -1;
  const Vocabulary v = Vocabulary::Train(set.images, SmallTree(), [&](double p) {
    EXPECT_GE(p, last_progress);
    last_progress = p;
  });
  EXPECT_DOUBLE_EQ(last_progress, 1.0);
  EXPECT_EQ(v.branching(), 6);
  EXPECT_GT(v.num_words(), 100);
  EXPECT_LE(v.num_words(), 216);
}

TEST(Vocabulary, MapsEveryDescriptorToTheWordOfTheGreedyDescent) {
  const TrainingSet set = MakeTrainingSet();
  const Vocabulary v = Vocabulary::Train(set.images, SmallTree());
  Rng rng(8);
  for (int i = 0; i < 500; ++i) {
    const Descriptor d = i % 2 ? RandomDescriptor(&rng) : Noisy(set.landmarks[i % 300], 10, &rng);
    ASSERT_EQ(v.Lookup(d.data(), 0), DescendByHand(v, d));
  }
  // Noisy observations of one landmark mostly share its word.
  int same = 0;
  const WordId word = v.Lookup(set.landmarks[7].data(), 0);
  for (int i = 0; i < 100; ++i) same += v.Lookup(Noisy(set.landmarks[7], 8, &rng).data(), 0) == word;
  EXPECT_GT(same, 80);
}

TEST(Vocabulary, ScoresAreOneForIdenticalVectorsAndSymmetric) {
  const TrainingSet set = MakeTrainingSet();
  const Vocabulary v = Vocabulary::Train(set.images, SmallTree());
  const BowVector a = v.Transform(ToMat(set.images[0]));
  const BowVector b = v.Transform(ToMat(set.images[1]));
  double total = 0;
  for (const auto& [word, weight] : a.entries) total += weight;
  EXPECT_NEAR(total, 1.0, 1e-5);
  EXPECT_NEAR(ScoreL1(a, a), 1.0, 1e-6);
  EXPECT_NEAR(ScoreL1(a, b), ScoreL1(b, a), 1e-9);
  EXPECT_LT(ScoreL1(a, b), 0.9);
  EXPECT_GE(ScoreL1(a, b), 0.0);
  EXPECT_EQ(CommonWords(a, b), CommonWords(b, a));
  EXPECT_EQ(CommonWords(a, a), static_cast<int>(a.size()));
}

TEST(Vocabulary, DirectIndexGroupsFeaturesUnderNodes) {
  const TrainingSet set = MakeTrainingSet();
  const Vocabulary v = Vocabulary::Train(set.images, SmallTree());
  FeatureVector features;
  const cv::Mat descriptors = ToMat(set.images[0]);
  v.Transform(descriptors, &features, 1);
  size_t total = 0;
  for (const auto& [node, indices] : features.nodes) {
    total += indices.size();
    for (int i : indices) {
      NodeId at_level;
      v.Lookup(descriptors.ptr<uint8_t>(i), 1, &at_level);
      ASSERT_EQ(at_level, node);
    }
  }
  EXPECT_EQ(total, set.images[0].size());
  EXPECT_LE(features.nodes.size(), 6u);
}

TEST(Vocabulary, SavesAndLoadsExactly) {
  testing::TempDir dir;
  const TrainingSet set = MakeTrainingSet();
  const Vocabulary v = Vocabulary::Train(set.images, SmallTree());
  v.Save(dir / "v.stitchvoc");
  const Vocabulary back = Vocabulary::Load(dir / "v.stitchvoc");
  EXPECT_EQ(back.num_words(), v.num_words());
  EXPECT_EQ(back.num_nodes(), v.num_nodes());
  const cv::Mat descriptors = ToMat(set.images[5]);
  const BowVector a = v.Transform(descriptors), b = back.Transform(descriptors);
  ASSERT_EQ(a.entries.size(), b.entries.size());
  for (size_t i = 0; i < a.entries.size(); ++i) {
    EXPECT_EQ(a.entries[i].first, b.entries[i].first);
    EXPECT_FLOAT_EQ(a.entries[i].second, b.entries[i].second);
  }
}

TEST(Vocabulary, CorruptOrTruncatedFilesAreRejected) {
  testing::TempDir dir;
  const Vocabulary v = Vocabulary::Train(MakeTrainingSet().images, SmallTree());
  v.Save(dir / "good.stitchvoc");
  std::ifstream in(dir / "good.stitchvoc", std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto write = [&](const std::string& name, const std::string& content) {
    std::ofstream(dir / name, std::ios::binary) << content;
    return dir / name;
  };
  std::string flipped = bytes;
  flipped[bytes.size() / 2] ^= 0x10;
  const auto message = [](const std::string& path) {
    try {
      Vocabulary::Load(path);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(message(write("flipped", flipped)).find("checksum"), std::string::npos);
  EXPECT_NE(message(write("short", bytes.substr(0, bytes.size() - 100))).find("truncated"), std::string::npos);
  EXPECT_NE(message(write("header", bytes.substr(0, 12))).find("truncated"), std::string::npos);
  EXPECT_NE(message(write("garbage", "hello world\n")).find("neither"), std::string::npos);
  EXPECT_NE(message(dir / "missing").find("not found"), std::string::npos);
}

// Writes a vocabulary in DBoW2's text format (as ORB-SLAM's ORBvoc.txt): nodes breadth-first,
// a node's id being its line number (root 0), each line naming its parent's id.
void WriteDbow2Text(const Vocabulary& v, const std::string& path) {
  std::ofstream out(path);
  out << v.branching() << " " << v.depth() << " 0 0\n";
  std::vector<std::pair<NodeId, int>> queue{{0, 0}};  // (our node, its DBoW2 id)
  int next_id = 1;
  for (size_t q = 0; q < queue.size(); ++q) {
    const auto& node = v.node(queue[q].first);
    for (int c = 0; c < node.num_children; ++c) {
      const NodeId child_index = node.first_child + c;
      const auto& child = v.node(child_index);
      out << queue[q].second << " " << (child.num_children == 0 ? 1 : 0);
      for (uint8_t byte : child.descriptor) out << " " << static_cast<int>(byte);
      out << " " << child.weight << "\n";
      queue.push_back({child_index, next_id++});
    }
  }
}

TEST(Vocabulary, ReadsDbow2TextVocabularies) {
  testing::TempDir dir;
  const TrainingSet set = MakeTrainingSet();
  const Vocabulary v = Vocabulary::Train(set.images, SmallTree());
  WriteDbow2Text(v, dir / "ORBvoc.txt");
  const Vocabulary text = Vocabulary::Load(dir / "ORBvoc.txt");
  EXPECT_EQ(text.num_words(), v.num_words());
  const cv::Mat descriptors = ToMat(set.images[9]);
  EXPECT_NEAR(ScoreL1(v.Transform(descriptors), text.Transform(descriptors)), 1.0, 1e-5);
  std::ofstream(dir / "bad.txt") << "10 6 1 0\n";
  EXPECT_THROW(Vocabulary::Load(dir / "bad.txt"), Error);
}

TEST(Vocabulary, WordsInEveryImageWeighNothing) {
  // One descriptor present in every training image: its IDF is log(1) = 0.
  TrainingSet set = MakeTrainingSet();
  const Descriptor everywhere = set.landmarks[0];
  for (auto& image : set.images) image.push_back(everywhere);
  const Vocabulary v = Vocabulary::Train(set.images, SmallTree());
  EXPECT_FLOAT_EQ(v.WordWeight(v.Lookup(everywhere.data(), 0)), 0.0f);
}

}  // namespace
}  // namespace stitch

namespace stitch {
namespace {

TEST(Vocabulary, ShippedDefaultLoadsAndSeparatesImages) {
  const Vocabulary v = Vocabulary::Load(std::string(STITCH_SOURCE_DIR) + "/vocabulary/default.stitchvoc");
  EXPECT_EQ(v.branching(), 10);
  EXPECT_EQ(v.depth(), 5);
  EXPECT_GT(v.num_words(), 50000);
  // Two unrelated random descriptor sets barely score; a set against itself scores 1.
  Rng rng(2);
  cv::Mat a(500, 32, CV_8U), b(500, 32, CV_8U);
  for (int i = 0; i < 500; ++i) {
    for (int j = 0; j < 32; ++j) {
      a.at<uint8_t>(i, j) = static_cast<uint8_t>(rng.NextU64());
      b.at<uint8_t>(i, j) = static_cast<uint8_t>(rng.NextU64());
    }
  }
  EXPECT_NEAR(ScoreL1(v.Transform(a), v.Transform(a)), 1.0, 1e-5);
  EXPECT_LT(ScoreL1(v.Transform(a), v.Transform(b)), 0.1);
}

}  // namespace
}  // namespace stitch
