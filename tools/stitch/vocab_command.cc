// stitch vocab: train a bag-of-words vocabulary, or describe one.

#include <cstdio>
#include <filesystem>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "stitch/features/keyframe_database.h"
#include "stitch/features/orb_extractor.h"
#include "stitch/features/vocabulary.h"
#include "stitch/io/image_sequence.h"
#include "stitch/util/args.h"
#include "stitch/util/error.h"
#include "stitch/util/time.h"
#include "tools/stitch/commands.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

void ShowProgress(const char* what, double fraction) {
  static int last = -1;
  const int percent = static_cast<int>(100 * fraction);
  if (percent == last) return;
  last = percent;
  std::printf("\r  %s %3d%%", what, percent);
  if (percent == 100) {
    std::printf("\n");
    last = -1;
  }
  std::fflush(stdout);
}

// Descriptors of one 640x480 (or smaller) image.
std::vector<Descriptor> Describe(OrbExtractor* extractor, const cv::Mat& image) {
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;
  extractor->Extract(image, &keypoints, &descriptors);
  std::vector<Descriptor> result;
  for (int i = 0; i < descriptors.rows; ++i) result.push_back(ToDescriptor(descriptors.ptr<uint8_t>(i)));
  return result;
}

// A large photo yields several camera-sized views: the photo scaled to 640, 1280 and 2560 pixels
// wide, cut into 640x480 tiles overlapping by half, so the vocabulary sees its texture at the
// scales a camera would.
std::vector<cv::Mat> CameraSizedViews(const cv::Mat& photo) {
  if (photo.cols <= 800 && photo.rows <= 600) return {photo};
  std::vector<cv::Mat> views;
  for (int width : {640, 1280, 2560}) {
    if (width > photo.cols) break;
    cv::Mat scaled;
    cv::resize(photo, scaled, cv::Size(width, cvRound(photo.rows * static_cast<double>(width) / photo.cols)), 0, 0,
               cv::INTER_AREA);
    for (int y = 0; y + 480 <= scaled.rows; y += 240) {
      for (int x = 0; x + 640 <= scaled.cols; x += 320) views.push_back(scaled(cv::Rect(x, y, 640, 480)).clone());
    }
  }
  return views;
}

int Train(int argc, char** argv) {
  std::vector<std::string> unused;
  std::string out, images_list, datasets_list;
  int every = 1, features = 1000;
  VocabularyTrainingOptions options;
  ArgParser args("stitch vocab train",
                 "Trains a bag-of-words vocabulary (hierarchical k-majority tree, TF-IDF) from ORB features of "
                 "images. Photos larger than 800x600 are cut into camera-sized views at three scales.");
  args.AddOption("--out", &out, "FILE", "where to write the vocabulary (.stitchvoc)");
  args.AddOption("--images", &images_list, "DIRS", "comma-separated folders of images (searched recursively)");
  args.AddOption("--datasets", &datasets_list, "PATHS", "comma-separated datasets (any kind stitch reads)");
  args.AddOption("--every", &every, "N", "from datasets, use every Nth frame");
  args.AddOption("--features", &features, "N", "ORB features per image");
  args.AddOption("--branching", &options.branching, "K", "children per node");
  args.AddOption("--depth", &options.depth, "L", "levels; at most K^L words");
  args.AddOption("--seed", &options.seed, "N", "seed of the k-means++ seeding");
  if (!args.Parse(argc, argv)) return args.exit_code();
  if (out.empty()) throw Error("--out FILE is required");
  if (images_list.empty() && datasets_list.empty()) throw Error("nothing to train on: give --images and/or --datasets");
  if (every < 1) throw Error("--every must be >= 1");
  OrbOptions orb;
  orb.num_features = features;
  OrbExtractor extractor(orb);
  const auto split = [](const std::string& list) {
    std::vector<std::string> parts;
    size_t start = 0;
    while (start <= list.size() && !list.empty()) {
      const size_t comma = list.find(',', start);
      parts.push_back(list.substr(start, comma - start));
      if (comma == std::string::npos) break;
      start = comma + 1;
    }
    return parts;
  };
  std::vector<std::vector<Descriptor>> training;
  size_t descriptors = 0;
  for (const std::string& folder : split(images_list)) {
    if (!fs::is_directory(folder)) throw Error(folder + ": not a folder");
    std::vector<fs::path> files;
    for (const auto& entry : fs::recursive_directory_iterator(folder)) {
      const std::string ext = entry.path().extension().string();
      if (entry.is_regular_file() &&
          (ext == ".jpg" || ext == ".jpeg" || ext == ".png" || ext == ".JPG" || ext == ".PNG")) {
        files.push_back(entry.path());
      }
    }
    std::sort(files.begin(), files.end());
    std::printf("%s: %zu images\n", folder.c_str(), files.size());
    for (size_t i = 0; i < files.size(); ++i) {
      const cv::Mat photo = cv::imread(files[i].string(), cv::IMREAD_GRAYSCALE);
      if (photo.empty()) {
        std::printf("\n  skipped %s: not a readable image\n", files[i].c_str());
        continue;
      }
      for (const cv::Mat& view : CameraSizedViews(photo)) {
        training.push_back(Describe(&extractor, view));
        descriptors += training.back().size();
      }
      ShowProgress("extracting", static_cast<double>(i + 1) / files.size());
    }
  }
  for (const std::string& dataset : split(datasets_list)) {
    auto sequence = OpenDataset(dataset);
    std::printf("%s\n", sequence->description().c_str());
    SequenceFrame frame;
    while (sequence->Next(&frame)) {
      if (frame.index % every != 0 || frame.image.empty()) continue;
      training.push_back(Describe(&extractor, frame.image));
      descriptors += training.back().size();
      if (sequence->size() > 0) ShowProgress("extracting", static_cast<double>(frame.index + 1) / sequence->size());
    }
    ShowProgress("extracting", 1.0);
  }
  std::printf("training k=%d L=%d on %zu descriptors from %zu images\n", options.branching, options.depth, descriptors,
              training.size());
  const Stopwatch clock;
  const Vocabulary vocabulary = Vocabulary::Train(training, options, [](double f) { ShowProgress("clustering", f); });
  vocabulary.Save(out);
  std::printf("wrote %s: %s, %.1f MB, trained in %.1f s\n", out.c_str(), vocabulary.Describe().c_str(),
              fs::file_size(out) / 1e6, clock.ElapsedSeconds());
  return 0;
}

int Info(int argc, char** argv) {
  std::vector<std::string> paths;
  ArgParser args("stitch vocab info", "Loads a vocabulary (stitch binary or DBoW2 text) and prints its shape.");
  args.AddPositional(&paths, "FILE", "vocabulary file");
  if (!args.Parse(argc, argv)) return args.exit_code();
  if (paths.empty()) throw Error("give a vocabulary file");
  const Stopwatch clock;
  const Vocabulary vocabulary = Vocabulary::Load(paths[0]);
  const double load_ms = clock.ElapsedMs();
  int zero_weight = 0;
  double max_weight = 0;
  for (int w = 0; w < vocabulary.num_words(); ++w) {
    zero_weight += vocabulary.WordWeight(w) == 0;
    max_weight = std::max(max_weight, static_cast<double>(vocabulary.WordWeight(w)));
  }
  std::printf("%s\n  %s\n  file %.1f MB, loaded in %.1f ms\n  IDF weights up to %.2f; %d words weigh 0\n",
              paths[0].c_str(), vocabulary.Describe().c_str(), fs::file_size(paths[0]) / 1e6, load_ms, max_weight,
              zero_weight);
  return 0;
}

// Fraction of frame a's view (rays through a grid of pixels, cut at `depth`) that frame b sees.
double ViewOverlap(const Camera& camera, const Rigid3d& world_from_a, const Rigid3d& world_from_b, double depth) {
  const Rigid3d b_from_a = world_from_b.Inverse() * world_from_a;
  int inside = 0, total = 0;
  for (int y = 0; y < 8; ++y) {
    for (int x = 0; x < 8; ++x) {
      const Eigen::Vector2d pixel((x + 0.5) * camera.width() / 8, (y + 0.5) * camera.height() / 8);
      const Eigen::Vector3d ray = camera.PixelToRay(pixel);
      const auto in_b = camera.Project(b_from_a * (ray * (depth / ray.z())));
      inside += in_b && camera.InImage(*in_b);
      ++total;
    }
  }
  return static_cast<double>(inside) / total;
}

int Retrieval(int argc, char** argv) {
  std::string dataset, vocabulary_path = std::string(STITCH_SOURCE_DIR) + "/vocabulary/default.stitchvoc";
  int every = 3, exclude = 30;
  double depth = 1.5, min_overlap = 0.5;
  ArgParser args("stitch vocab retrieval",
                 "Measures place recognition on a sequence with ground truth: every Nth frame goes into a keyframe "
                 "database; each is queried, ignoring frames within --exclude of it; a candidate is a true neighbour "
                 "when ground truth says the two views overlap by at least --min-overlap (rays through the image cut "
                 "at --depth).");
  args.AddOption("--dataset", &dataset, "PATH", "sequence with ground truth");
  args.AddOption("--vocabulary", &vocabulary_path, "FILE", "vocabulary to evaluate");
  args.AddOption("--every", &every, "N", "use every Nth frame");
  args.AddOption("--exclude", &exclude, "N", "ignore candidates within N frames of the query");
  args.AddOption("--depth", &depth, "M", "scene depth for the overlap, metres");
  args.AddOption("--min-overlap", &min_overlap, "F", "overlap that makes two frames neighbours");
  if (!args.Parse(argc, argv)) return args.exit_code();
  if (dataset.empty()) throw Error("--dataset PATH is required");
  const Vocabulary vocabulary = Vocabulary::Load(vocabulary_path);
  auto sequence = OpenDataset(dataset);
  if (sequence->ground_truth().empty()) throw Error(dataset + ": no ground truth");
  OrbExtractor extractor{OrbOptions{}};
  struct Item {
    int index;
    Rigid3d world_from_cam;
    BowVector bow;
  };
  std::vector<Item> items;
  SequenceFrame frame;
  while (sequence->Next(&frame)) {
    if (frame.index % every != 0 || frame.image.empty()) continue;
    const auto pose = sequence->ground_truth().PoseAt(frame.t_ns);
    if (!pose) continue;
    std::vector<cv::KeyPoint> keypoints;
    cv::Mat descriptors;
    extractor.Extract(frame.image, &keypoints, &descriptors);
    items.push_back({frame.index, *pose, vocabulary.Transform(descriptors)});
  }
  KeyframeDatabase database;
  for (size_t i = 0; i < items.size(); ++i) database.Add(static_cast<int64_t>(i), 0, items[i].bow);
  int queries = 0, top1 = 0, top5 = 0;
  double average_precision = 0;
  for (size_t q = 0; q < items.size(); ++q) {
    std::vector<bool> neighbour(items.size(), false);
    int positives = 0;
    for (size_t j = 0; j < items.size(); ++j) {
      if (std::abs(items[j].index - items[q].index) <= exclude) continue;
      neighbour[j] =
          ViewOverlap(sequence->camera(), items[q].world_from_cam, items[j].world_from_cam, depth) >= min_overlap;
      positives += neighbour[j];
    }
    if (positives == 0) continue;
    auto candidates = database.Query(items[q].bow);
    candidates.erase(
        std::remove_if(candidates.begin(), candidates.end(),
                       [&](const auto& c) { return std::abs(items[c.keyframe_id].index - items[q].index) <= exclude; }),
        candidates.end());
    std::sort(candidates.begin(), candidates.end(), [](const auto& a, const auto& b) { return a.score > b.score; });
    ++queries;
    int hits = 0;
    double precision_sum = 0;
    for (size_t r = 0; r < candidates.size(); ++r) {
      if (!neighbour[candidates[r].keyframe_id]) continue;
      ++hits;
      precision_sum += static_cast<double>(hits) / (r + 1);
      if (r == 0) ++top1;
    }
    for (size_t r = 0; r < std::min<size_t>(5, candidates.size()); ++r) {
      if (neighbour[candidates[r].keyframe_id]) {
        ++top5;
        break;
      }
    }
    average_precision += precision_sum / positives;
  }
  std::printf(
      "%s\n  vocabulary %s\n  %zu frames in the database, %d queries with a true neighbour more than %d frames away\n"
      "  precision@1 %.3f   hit rate in top 5 %.3f   mean average precision %.3f\n",
      sequence->description().c_str(), vocabulary.Describe().c_str(), items.size(), queries, exclude,
      queries ? static_cast<double>(top1) / queries : 0.0, queries ? static_cast<double>(top5) / queries : 0.0,
      queries ? average_precision / queries : 0.0);
  return 0;
}

}  // namespace

int VocabCommand(int argc, char** argv) {
  const char* usage =
      "usage: stitch vocab train --out FILE [--images DIRS] [--datasets PATHS] [options]\n"
      "       stitch vocab info FILE\n"
      "       stitch vocab retrieval --dataset PATH [options]\n(each with --help)\n";
  if (argc < 2 || std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h") {
    std::fputs(usage, argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  const std::string sub = argv[1];
  std::string program = "stitch vocab " + sub;
  argv[1] = program.data();
  try {
    if (sub == "train") return Train(argc - 1, argv + 1);
    if (sub == "info") return Info(argc - 1, argv + 1);
    if (sub == "retrieval") return Retrieval(argc - 1, argv + 1);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch vocab %s: %s\n", sub.c_str(), e.what());
    return 1;
  }
  std::fprintf(stderr, "stitch vocab: unknown command '%s'\n%s", sub.c_str(), usage);
  return 2;
}

}  // namespace stitch
