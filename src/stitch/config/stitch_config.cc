#include "stitch/config/stitch_config.h"

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

#include <opencv2/core/utility.hpp>

#include "stitch/io/calibration.h"
#include "stitch/util/child_process.h"
#include "stitch/util/log.h"
#include "stitch/util/options.h"
#include "stitch/util/text_file.h"

namespace stitch {

StitchConfig LoadStitchConfig(const std::string& path) {
  if (path.empty()) {
    StitchConfig defaults;
    CheckOptions(defaults, "default configuration");
    return defaults;
  }
  return ReadOptions<StitchConfig>(LoadYamlFile(path), path);
}

void ApplyProcessSettings(const StitchConfig& config) {
  // OpenCV's count: 1 (or 0) runs each operation on the calling thread, a negative one its default.
  cv::setNumThreads(config.opencv_threads == 0 ? -1 : config.opencv_threads);
}

std::string DefaultVocabularyPath() {
  // The source tree's, in a build; beside an installed program, <prefix>/share/stitch.
  if (std::filesystem::exists(STITCH_DEFAULT_VOCABULARY)) return STITCH_DEFAULT_VOCABULARY;
  const std::filesystem::path installed =
      std::filesystem::path(ExecutableDir()) / ".." / "share" / "stitch" / "default.stitchvoc";
  return std::filesystem::exists(installed) ? installed.lexically_normal().string() : STITCH_DEFAULT_VOCABULARY;
}

std::string VocabularyDoubts(const Vocabulary& vocabulary) {
  constexpr int kFewWords = 10000;
  if (vocabulary.num_words() >= kFewWords) return "";
  return "the vocabulary has only " + std::to_string(vocabulary.num_words()) +
         " words: its bags of words tell few places apart, so relocalization and merging find few right "
         "candidates (the shipped one has about 100,000; ORB-SLAM's about a million; `stitch vocab` trains one)";
}

Vocabulary LoadVocabulary(const StitchConfig& config) {
  const std::string path = config.vocabulary.empty() ? DefaultVocabularyPath() : config.vocabulary;
  Vocabulary vocabulary = Vocabulary::Load(path);
  STITCH_LOG(INFO) << "vocabulary " << path << ": " << vocabulary.num_words()
                   << " words (k = " << vocabulary.branching() << ", L = " << vocabulary.depth() << ")";
  if (const std::string doubt = VocabularyDoubts(vocabulary); !doubt.empty()) {
    STITCH_LOG(WARNING) << path << ": " << doubt;
  }
  return vocabulary;
}

StitchConfig LoadStitchConfig(const std::string& path, const std::vector<std::string>& settings) {
  return ApplySettings(LoadStitchConfig(path), settings);
}

StitchConfig ApplySettings(StitchConfig config, const std::vector<std::string>& settings) {
  if (settings.empty()) return config;
  YAML::Node root(YAML::NodeType::Map);
  for (const std::string& setting : settings) {
    const size_t equals = setting.find('=');
    if (equals == std::string::npos || equals == 0) throw Error("setting '" + setting + "': expected key.path=value");
    std::vector<std::string> path;
    std::stringstream keys(setting.substr(0, equals));
    for (std::string key; std::getline(keys, key, '.');) {
      if (key.empty()) throw Error("setting '" + setting + "': empty key");
      path.push_back(key);
    }
    // yaml-cpp's operator[] returns handles into the tree: walk by reassigning a copy.
    std::vector<YAML::Node> chain{root};
    for (size_t i = 0; i + 1 < path.size(); ++i) {
      YAML::Node next = chain.back()[path[i]];
      if (!next.IsDefined() || next.IsNull()) next = YAML::Node(YAML::NodeType::Map);
      chain.back()[path[i]] = next;
      chain.push_back(chain.back()[path[i]]);
    }
    YAML::Node value;
    try {
      value = YAML::Load(setting.substr(equals + 1));
    } catch (const YAML::Exception& e) {
      throw Error("setting '" + setting + "': " + e.what());
    }
    chain.back()[path.back()] = value;
  }
  return ReadOptions<StitchConfig>(root, "--set", std::move(config));
}

StitchConfig ApplySettings(StitchConfig config, const std::string& settings) {
  std::vector<std::string> list;
  std::stringstream items(settings);
  for (std::string setting; std::getline(items, setting, ',');) list.push_back(setting);
  return ApplySettings(std::move(config), list);
}

std::string TextSetting(const std::string& key, const std::string& value) {
  std::string quoted = "'";
  for (char c : value) quoted += c == '\'' ? std::string("''") : std::string(1, c);
  return key + "=" + quoted + "'";
}

std::string NumberSetting(const std::string& key, double value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.17g", value);
  return key + "=" + text;
}

std::vector<std::string> OrbSlamFeatureSettings(const std::string& calibration_path) {
  static const std::map<std::string, std::string> kStitchKeys = {{"nFeatures", "num_features"},
                                                                 {"scaleFactor", "scale_factor"},
                                                                 {"nLevels", "num_levels"},
                                                                 {"iniThFAST", "fast_threshold"},
                                                                 {"minThFAST", "min_fast_threshold"}};
  std::vector<std::string> settings;
  for (const auto& [name, value] : ReadOrbExtractorSettings(calibration_path)) {
    settings.push_back(NumberSetting("tracker.tracking.orb." + kStitchKeys.at(name), value));
  }
  return settings;
}

std::vector<std::string> CommandLineSettings(const std::string& calibration_path, const std::string& vocabulary,
                                             const std::vector<std::string>& settings) {
  std::vector<std::string> all;
  if (!calibration_path.empty()) {
    all = OrbSlamFeatureSettings(calibration_path);
    if (const auto line_delay_us = ReadLineDelayUs(calibration_path)) {
      all.push_back(NumberSetting("tracker.tracking.rolling_shutter_line_us", *line_delay_us));
    }
  }
  if (!vocabulary.empty()) all.push_back(TextSetting("vocabulary", vocabulary));
  all.insert(all.end(), settings.begin(), settings.end());
  return all;
}

void SaveStitchConfig(const StitchConfig& config, const std::string& path) {
  WriteFileAtomically(path,
                      "# stitch configuration (resolved: every setting, defaults included)\n" + DumpOptions(config));
}

}  // namespace stitch
