#pragma once
// A hierarchical vocabulary tree for 256-bit ORB descriptors (Nister & Stewenius 2006; Galvez-
// Lopez & Tardos 2012): k-majority clustering with k-means++ seeding at every node, `depth`
// levels of `branching` children, leaves are words with an IDF weight. Transform descends the
// tree (depth x branching Hamming distances per descriptor), weights words by TF-IDF and
// L1-normalizes. Immutable after construction: Transform is const and thread-safe.
//
// Files: our compact binary format (.stitchvoc: magic, version, shape, nodes, checksum; loads
// in milliseconds), and DBoW2's text format (ORBvoc.txt), read only.

#include <algorithm>
#include <functional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "stitch/features/bow.h"
#include "stitch/features/descriptor.h"

namespace stitch {

struct VocabularyTrainingOptions {
  int branching = 10;       // k
  int depth = 5;            // L
  int max_iterations = 15;  // k-majority iterations per node
  int seed = 1;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("branching", branching, "children per node (k)");
    v("depth", depth, "levels below the root (L); words <= k^L");
    v("max_iterations", max_iterations, "k-majority iterations per node");
    v("seed", seed, "k-means++ seeding is deterministic from this");
  }
  bool Check(std::string* why) const;
};

class Vocabulary {
 public:
  struct Node {
    Descriptor descriptor{};
    uint32_t first_child = 0;  // children are [first_child, first_child + num_children)
    uint16_t num_children = 0;
    int32_t word = -1;  // >= 0 for leaves
    float weight = 0;   // IDF, leaves only
  };

  Vocabulary() = default;

  // Trains on descriptors grouped per training image (the IDF counts images). `progress` is
  // called with a fraction in [0, 1]. Throws stitch::Error on invalid options or too few
  // descriptors.
  static Vocabulary Train(const std::vector<std::vector<Descriptor>>& images, const VocabularyTrainingOptions& options,
                          const std::function<void(double)>& progress = nullptr);

  // Reads our binary format or DBoW2 text (detected). Throws stitch::Error naming the file for
  // a missing, truncated, corrupt or foreign file.
  static Vocabulary Load(const std::string& path);
  void Save(const std::string& path) const;

  bool empty() const { return nodes_.empty(); }
  int branching() const { return branching_; }
  int depth() const { return depth_; }
  int num_words() const { return static_cast<int>(words_.size()); }
  int num_nodes() const { return static_cast<int>(nodes_.size()); }
  const Node& node(NodeId id) const { return nodes_[id]; }
  float WordWeight(WordId word) const { return nodes_[words_[word]].weight; }
  std::string Describe() const;

  // The word of one descriptor and the node it passes at `level` (0 = root).
  WordId Lookup(const uint8_t* descriptor, int level, NodeId* node_at_level = nullptr) const;

  // TF-IDF vector of a set of descriptors (N x 32 CV_8U); when `features` is given, also the
  // direct index at `direct_index_level` (0 = root; ORB-SLAM's choice is L - 4; -1: this
  // vocabulary's direct_index_level()).
  BowVector Transform(const cv::Mat& descriptors, FeatureVector* features = nullptr, int direct_index_level = -1) const;
  // The level whose nodes group features for matching by bag of words (the direct index): every
  // user of a vocabulary (tracker, mapper, merger) must group at the same level, so it is the
  // vocabulary's: level 2 below the root (at most the depth).
  int direct_index_level() const { return std::min(kDirectIndexLevel, depth_); }

 private:
  static constexpr int kDirectIndexLevel = 2;
  int branching_ = 0;
  int depth_ = 0;
  std::vector<Node> nodes_;    // node 0 is the root
  std::vector<NodeId> words_;  // word -> node
};

}  // namespace stitch
