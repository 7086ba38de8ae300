#include "stitch/features/vocabulary.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <numeric>
#include <set>
#include <sstream>

#include "stitch/util/error.h"
#include "stitch/util/rng.h"
#include "stitch/util/text_file.h"

namespace stitch {
namespace {

constexpr char kMagic[8] = {'S', 'T', 'V', 'O', 'C', 'A', 'B', '\0'};
constexpr uint32_t kFormatVersion = 1;
constexpr size_t kNodeBytes = 32 + 4 + 2 + 4 + 4;
constexpr size_t kHeaderBytes = 8 + 4 * 5;
// Above this many descriptors a node's centres are found on a random subset, then every
// descriptor is assigned (the centres of 20k and of 500k descriptors barely differ).
constexpr size_t kClusteringSample = 20000;

uint64_t Fnv1a(const uint8_t* data, size_t size) {
  uint64_t hash = 0xcbf29ce484222325ULL;
  for (size_t i = 0; i < size; ++i) {
    hash ^= data[i];
    hash *= 0x100000001b3ULL;
  }
  return hash;
}

template <class T>
void Put(std::vector<uint8_t>* out, T value) {
  const auto* bytes = reinterpret_cast<const uint8_t*>(&value);  // little-endian hosts only
  out->insert(out->end(), bytes, bytes + sizeof(T));
}

template <class T>
T Get(const uint8_t*& cursor) {
  T value;
  std::memcpy(&value, cursor, sizeof(T));
  cursor += sizeof(T);
  return value;
}

// Bitwise majority of a set of descriptors.
Descriptor Majority(const std::vector<Descriptor>& all, const std::vector<uint32_t>& members) {
  std::array<int, 256> ones{};
  for (uint32_t m : members) {
    const Descriptor& d = all[m];
    for (int byte = 0; byte < 32; ++byte) {
      const uint8_t value = d[byte];
      for (int bit = 0; bit < 8; ++bit) ones[byte * 8 + bit] += (value >> bit) & 1;
    }
  }
  Descriptor centre{};
  const int half = static_cast<int>(members.size()) / 2;
  for (int i = 0; i < 256; ++i) {
    if (ones[i] > half) centre[i / 8] |= static_cast<uint8_t>(1u << (i % 8));
  }
  return centre;
}

int Nearest(const Descriptor& d, const std::vector<Descriptor>& centres) {
  int best = 0, best_distance = 257;
  for (size_t c = 0; c < centres.size(); ++c) {
    const int distance = HammingDistance(d, centres[c]);
    if (distance < best_distance) {
      best_distance = distance;
      best = static_cast<int>(c);
    }
  }
  return best;
}

// k-majority with k-means++ seeding on `members`; returns the centres (fewer than k when the
// members hold fewer distinct descriptors).
std::vector<Descriptor> Cluster(const std::vector<Descriptor>& all, std::vector<uint32_t> members, int k,
                                int max_iterations, Rng* rng) {
  if (members.size() > kClusteringSample) {
    for (size_t i = 0; i < kClusteringSample; ++i) {
      std::swap(members[i], members[i + rng->NextU64() % (members.size() - i)]);
    }
    members.resize(kClusteringSample);
  }
  // k-means++: each next centre drawn with probability proportional to squared distance.
  std::vector<Descriptor> centres{all[members[rng->NextU64() % members.size()]]};
  std::vector<double> d2(members.size());
  for (size_t i = 0; i < members.size(); ++i) {
    const double d = HammingDistance(all[members[i]], centres[0]);
    d2[i] = d * d;
  }
  while (static_cast<int>(centres.size()) < k) {
    const double total = std::accumulate(d2.begin(), d2.end(), 0.0);
    if (total <= 0) break;  // every member equals a centre already
    double target = rng->Uniform() * total;
    size_t pick = 0;
    for (; pick + 1 < members.size() && target >= d2[pick]; ++pick) target -= d2[pick];
    centres.push_back(all[members[pick]]);
    for (size_t i = 0; i < members.size(); ++i) {
      const double d = HammingDistance(all[members[i]], centres.back());
      d2[i] = std::min(d2[i], d * d);
    }
  }
  std::vector<int> assignment(members.size(), -1);
  for (int iteration = 0; iteration < max_iterations; ++iteration) {
    bool changed = false;
    std::vector<std::vector<uint32_t>> groups(centres.size());
    for (size_t i = 0; i < members.size(); ++i) {
      const int c = Nearest(all[members[i]], centres);
      changed |= c != assignment[i];
      assignment[i] = c;
      groups[c].push_back(members[i]);
    }
    if (!changed) break;
    for (size_t c = 0; c < centres.size(); ++c) {
      if (!groups[c].empty()) centres[c] = Majority(all, groups[c]);
    }
  }
  return centres;
}

}  // namespace

bool VocabularyTrainingOptions::Check(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (branching < 2 || branching > 64) return fail("vocabulary branching must be in [2, 64]");
  if (depth < 1 || depth > 8) return fail("vocabulary depth must be in [1, 8]");
  if (std::pow(branching, depth) > 5e7) return fail("vocabulary branching^depth must be at most 5e7 words");
  if (max_iterations < 1) return fail("vocabulary max_iterations must be >= 1");
  return true;
}

Vocabulary Vocabulary::Train(const std::vector<std::vector<Descriptor>>& images,
                             const VocabularyTrainingOptions& options, const std::function<void(double)>& progress) {
  std::string why;
  if (!options.Check(&why)) throw Error(why);
  std::vector<Descriptor> all;
  for (const auto& image : images) all.insert(all.end(), image.begin(), image.end());
  if (all.size() < static_cast<size_t>(options.branching)) {
    throw Error("vocabulary training: " + std::to_string(all.size()) + " descriptors are too few");
  }
  Vocabulary vocabulary;
  vocabulary.branching_ = options.branching;
  vocabulary.depth_ = options.depth;
  vocabulary.nodes_.emplace_back();
  Rng rng(static_cast<uint64_t>(options.seed) * 0x9E3779B97F4A7C15ULL + 7);

  // Depth-first: cluster a node's descriptors, create its children together (contiguous), then
  // descend into each child.
  struct Work {
    NodeId node;
    int level;
    std::vector<uint32_t> members;
  };
  std::vector<Work> stack;
  std::vector<uint32_t> everyone(all.size());
  std::iota(everyone.begin(), everyone.end(), 0u);
  stack.push_back({0, 0, std::move(everyone)});
  size_t leaves_done = 0;
  while (!stack.empty()) {
    Work work = std::move(stack.back());
    stack.pop_back();
    const bool last_level = work.level >= options.depth;
    std::vector<Descriptor> centres;
    if (!last_level && work.members.size() > 1) {
      centres = Cluster(all, work.members, options.branching, options.max_iterations, &rng);
    }
    if (centres.size() < 2) {  // a leaf: last level, or nothing left to separate
      vocabulary.nodes_[work.node].word = static_cast<int32_t>(vocabulary.words_.size());
      vocabulary.words_.push_back(work.node);
      leaves_done += work.members.size();
      if (progress) progress(0.95 * leaves_done / all.size());
      continue;
    }
    std::vector<std::vector<uint32_t>> groups(centres.size());
    for (uint32_t m : work.members) groups[Nearest(all[m], centres)].push_back(m);
    const NodeId first = static_cast<NodeId>(vocabulary.nodes_.size());
    vocabulary.nodes_[work.node].first_child = first;
    vocabulary.nodes_[work.node].num_children = static_cast<uint16_t>(centres.size());
    for (const auto& centre : centres) {
      Node child;
      child.descriptor = centre;
      vocabulary.nodes_.push_back(child);
    }
    for (size_t c = centres.size(); c-- > 0;) {
      stack.push_back({first + static_cast<NodeId>(c), work.level + 1, std::move(groups[c])});
    }
  }
  // IDF: log(images / images containing the word).
  std::vector<int> images_with_word(vocabulary.words_.size(), 0);
  for (const auto& image : images) {
    std::set<WordId> seen;
    for (const auto& d : image) seen.insert(vocabulary.Lookup(d.data(), 0));
    for (WordId w : seen) ++images_with_word[w];
  }
  const double n = static_cast<double>(images.size());
  for (size_t w = 0; w < vocabulary.words_.size(); ++w) {
    vocabulary.nodes_[vocabulary.words_[w]].weight = static_cast<float>(std::log(n / std::max(1, images_with_word[w])));
  }
  if (progress) progress(1.0);
  return vocabulary;
}

WordId Vocabulary::Lookup(const uint8_t* descriptor, int level, NodeId* node_at_level) const {
  NodeId node = 0;
  int current = 0;
  if (node_at_level) *node_at_level = 0;
  while (nodes_[node].num_children > 0) {
    const Node& parent = nodes_[node];
    NodeId best = parent.first_child;
    int best_distance = 257;
    for (NodeId c = parent.first_child; c < parent.first_child + parent.num_children; ++c) {
      const int distance = HammingDistance(descriptor, nodes_[c].descriptor.data());
      if (distance < best_distance) {
        best_distance = distance;
        best = c;
      }
    }
    node = best;
    ++current;
    if (node_at_level && current <= level) *node_at_level = node;
  }
  return static_cast<WordId>(nodes_[node].word);
}

BowVector Vocabulary::Transform(const cv::Mat& descriptors, FeatureVector* features, int direct_index_level) const {
  if (direct_index_level < 0) direct_index_level = this->direct_index_level();
  BowVector bow;
  if (empty() || descriptors.empty()) return bow;
  if (descriptors.cols != kDescriptorBytes || descriptors.type() != CV_8U) {
    throw Error("Vocabulary::Transform: expected N x 32 CV_8U descriptors");
  }
  std::vector<std::pair<WordId, float>> raw;
  raw.reserve(descriptors.rows);
  std::vector<std::pair<NodeId, int>> direct;
  if (features) direct.reserve(descriptors.rows);
  for (int i = 0; i < descriptors.rows; ++i) {
    NodeId node = 0;
    const WordId word = Lookup(descriptors.ptr<uint8_t>(i), direct_index_level, features ? &node : nullptr);
    const float weight = nodes_[words_[word]].weight;
    if (weight > 0) raw.push_back({word, weight});
    if (features) direct.push_back({node, i});
  }
  std::sort(raw.begin(), raw.end());
  double total = 0;
  for (const auto& [word, weight] : raw) {
    if (!bow.entries.empty() && bow.entries.back().first == word) {
      bow.entries.back().second += weight;
    } else {
      bow.entries.push_back({word, weight});
    }
    total += weight;
  }
  if (total > 0) {
    for (auto& entry : bow.entries) entry.second = static_cast<float>(entry.second / total);
  }
  if (features) {
    std::sort(direct.begin(), direct.end());
    features->nodes.clear();
    for (const auto& [node, index] : direct) {
      if (features->nodes.empty() || features->nodes.back().first != node) features->nodes.push_back({node, {}});
      features->nodes.back().second.push_back(index);
    }
  }
  return bow;
}

std::string Vocabulary::Describe() const {
  std::ostringstream s;
  s << "k=" << branching_ << " L=" << depth_ << ", " << num_words() << " words, " << num_nodes() << " nodes";
  return s.str();
}

void Vocabulary::Save(const std::string& path) const {
  std::vector<uint8_t> bytes;
  bytes.reserve(kHeaderBytes + nodes_.size() * kNodeBytes + 8);
  bytes.insert(bytes.end(), kMagic, kMagic + 8);
  Put<uint32_t>(&bytes, kFormatVersion);
  Put<uint32_t>(&bytes, static_cast<uint32_t>(branching_));
  Put<uint32_t>(&bytes, static_cast<uint32_t>(depth_));
  Put<uint32_t>(&bytes, static_cast<uint32_t>(nodes_.size()));
  Put<uint32_t>(&bytes, static_cast<uint32_t>(words_.size()));
  for (const Node& node : nodes_) {
    bytes.insert(bytes.end(), node.descriptor.begin(), node.descriptor.end());
    Put<uint32_t>(&bytes, node.first_child);
    Put<uint16_t>(&bytes, node.num_children);
    Put<int32_t>(&bytes, node.word);
    Put<float>(&bytes, node.weight);
  }
  Put<uint64_t>(&bytes, Fnv1a(bytes.data(), bytes.size()));
  WriteFileAtomically(path, std::string(reinterpret_cast<const char*>(bytes.data()), bytes.size()));
}

namespace {

// DBoW2's text format: "k L scoring weighting", then one line per node after the root:
// "parent is_leaf d0 ... d31 weight" (ORB descriptors as 32 decimal bytes).
Vocabulary::Node ParseDbow2Line(const char*& p, const char* end, int* parent, bool* is_leaf, const std::string& path,
                                int line) {
  const auto next_number = [&](auto* value) {
    while (p < end && (*p == ' ' || *p == '\t' || *p == '\r')) ++p;
    if (p >= end || *p == '\n') throw Error(path + ":" + std::to_string(line) + ": line ends early (DBoW2 text)");
    char* stop = nullptr;
    if constexpr (std::is_floating_point_v<std::remove_pointer_t<decltype(value)>>) {
      *value = std::strtod(p, &stop);
    } else {
      *value = std::strtol(p, &stop, 10);
    }
    if (stop == p) throw Error(path + ":" + std::to_string(line) + ": not a number (DBoW2 text)");
    p = stop;
  };
  Vocabulary::Node node;
  long parent_value = 0, leaf_value = 0;
  next_number(&parent_value);
  next_number(&leaf_value);
  for (int i = 0; i < 32; ++i) {
    long byte = 0;
    next_number(&byte);
    if (byte < 0 || byte > 255) throw Error(path + ":" + std::to_string(line) + ": descriptor byte out of range");
    node.descriptor[i] = static_cast<uint8_t>(byte);
  }
  double weight = 0;
  next_number(&weight);
  while (p < end && *p != '\n') ++p;
  if (p < end) ++p;
  *parent = static_cast<int>(parent_value);
  *is_leaf = leaf_value != 0;
  node.weight = static_cast<float>(weight);
  return node;
}

}  // namespace

Vocabulary Vocabulary::Load(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(path + ": vocabulary file not found or not readable");
  std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  Vocabulary vocabulary;
  if (bytes.size() >= 8 && std::memcmp(bytes.data(), kMagic, 8) == 0) {
    if (bytes.size() < kHeaderBytes + 8) throw Error(path + ": truncated vocabulary (header incomplete)");
    const uint8_t* cursor = bytes.data() + 8;
    const uint32_t version = Get<uint32_t>(cursor);
    if (version != kFormatVersion) {
      throw Error(path + ": vocabulary format version " + std::to_string(version) + ", this stitch reads version " +
                  std::to_string(kFormatVersion));
    }
    vocabulary.branching_ = static_cast<int>(Get<uint32_t>(cursor));
    vocabulary.depth_ = static_cast<int>(Get<uint32_t>(cursor));
    const uint32_t num_nodes = Get<uint32_t>(cursor);
    const uint32_t num_words = Get<uint32_t>(cursor);
    const size_t expected = kHeaderBytes + static_cast<size_t>(num_nodes) * kNodeBytes + 8;
    if (bytes.size() != expected) {
      throw Error(path + ": vocabulary is " + std::to_string(bytes.size()) + " bytes but its header promises " +
                  std::to_string(expected) + " (truncated or corrupt)");
    }
    uint64_t stored;
    std::memcpy(&stored, bytes.data() + bytes.size() - 8, 8);
    if (stored != Fnv1a(bytes.data(), bytes.size() - 8))
      throw Error(path + ": vocabulary checksum mismatch (corrupt file)");
    vocabulary.nodes_.resize(num_nodes);
    vocabulary.words_.assign(num_words, 0);
    for (uint32_t i = 0; i < num_nodes; ++i) {
      Node& node = vocabulary.nodes_[i];
      std::memcpy(node.descriptor.data(), cursor, 32);
      cursor += 32;
      node.first_child = Get<uint32_t>(cursor);
      node.num_children = Get<uint16_t>(cursor);
      node.word = Get<int32_t>(cursor);
      node.weight = Get<float>(cursor);
      const bool children_ok =
          node.num_children == 0 || (node.first_child > i && node.first_child + node.num_children <= num_nodes);
      const bool word_ok =
          node.num_children > 0 ? node.word == -1 : (node.word >= 0 && static_cast<uint32_t>(node.word) < num_words);
      if (!children_ok || !word_ok) throw Error(path + ": vocabulary node " + std::to_string(i) + " is inconsistent");
      if (node.word >= 0) vocabulary.words_[node.word] = i;
    }
    return vocabulary;
  }
  // DBoW2 text.
  const char* p = reinterpret_cast<const char*>(bytes.data());
  const char* end = p + bytes.size();
  int k = 0, depth = 0, scoring = -1, weighting = -1;
  {
    const char* line_end = std::find(p, end, '\n');
    std::istringstream header(std::string(p, line_end));
    header >> k >> depth >> scoring >> weighting;
    if (!header || k < 2 || depth < 1) {
      throw Error(path + ": neither a stitch vocabulary nor DBoW2 text (first line should be 'k L scoring weighting')");
    }
    if (scoring != 0 || weighting != 0) {
      throw Error(path + ": DBoW2 vocabulary with scoring " + std::to_string(scoring) + " / weighting " +
                  std::to_string(weighting) + "; stitch uses L1 scoring and TF-IDF (0 0)");
    }
    p = line_end < end ? line_end + 1 : end;
  }
  // Read nodes as DBoW2 numbers them (root 0, then one per line), then renumber breadth-first so
  // each node's children are contiguous.
  std::vector<Node> file_nodes(1);
  std::vector<std::vector<int>> children(1);
  std::vector<int> file_words;
  int line = 1;
  while (p < end) {
    ++line;
    if (*p == '\n' || *p == '\r') {
      ++p;
      continue;
    }
    int parent = 0;
    bool is_leaf = false;
    Node node = ParseDbow2Line(p, end, &parent, &is_leaf, path, line);
    const int id = static_cast<int>(file_nodes.size());
    if (parent < 0 || parent >= id) throw Error(path + ":" + std::to_string(line) + ": parent id out of order");
    node.word = is_leaf ? static_cast<int32_t>(file_words.size()) : -1;
    if (is_leaf) file_words.push_back(id);
    file_nodes.push_back(node);
    children.emplace_back();
    children[parent].push_back(id);
  }
  if (file_words.empty()) throw Error(path + ": DBoW2 vocabulary without words");
  vocabulary.branching_ = k;
  vocabulary.depth_ = depth;
  vocabulary.words_.assign(file_words.size(), 0);
  std::vector<int> order{0};
  vocabulary.nodes_.push_back(file_nodes[0]);
  for (size_t i = 0; i < order.size(); ++i) {
    const int file_id = order[i];
    Node& node = vocabulary.nodes_[i];
    node.first_child = static_cast<uint32_t>(order.size());
    node.num_children = static_cast<uint16_t>(children[file_id].size());
    if (node.num_children > 0) node.word = -1;
    for (int child : children[file_id]) {
      order.push_back(child);
      vocabulary.nodes_.push_back(file_nodes[child]);
    }
    if (vocabulary.nodes_[i].num_children == 0) {
      if (vocabulary.nodes_[i].word < 0) throw Error(path + ": DBoW2 node without children that is not a leaf");
      vocabulary.words_[vocabulary.nodes_[i].word] = static_cast<NodeId>(i);
    }
  }
  return vocabulary;
}

}  // namespace stitch
