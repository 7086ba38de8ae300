#include "services/config/stitch_config.h"

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "stitch/util/child_process.h"
#include "stitch/util/options.h"

namespace stitch {

StitchConfig LoadStitchConfig(const std::string& path) {
  if (path.empty()) {
    StitchConfig defaults;
    CheckOptions(defaults, "default configuration");
    return defaults;
  }
  return ReadOptions<StitchConfig>(LoadYamlFile(path), path);
}

std::string DefaultVocabularyPath() {
  // The source tree's, in a build; beside an installed program, <prefix>/share/stitch.
  if (std::filesystem::exists(STITCH_DEFAULT_VOCABULARY)) return STITCH_DEFAULT_VOCABULARY;
  const std::filesystem::path installed =
      std::filesystem::path(ExecutableDir()) / ".." / "share" / "stitch" / "default.stitchvoc";
  return std::filesystem::exists(installed) ? installed.lexically_normal().string() : STITCH_DEFAULT_VOCABULARY;
}

Vocabulary LoadVocabulary(const StitchConfig& config) {
  return Vocabulary::Load(config.vocabulary.empty() ? DefaultVocabularyPath() : config.vocabulary);
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

void SaveStitchConfig(const StitchConfig& config, const std::string& path) {
  std::ofstream out(path);
  if (!out) throw Error(path + ": cannot write");
  out << "# stitch configuration (resolved: every setting, defaults included)\n" << DumpOptions(config);
  if (!out) throw Error(path + ": write failed");
}

}  // namespace stitch
