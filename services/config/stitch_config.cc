#include "services/config/stitch_config.h"

#include <fstream>

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

std::string DefaultVocabularyPath() { return STITCH_DEFAULT_VOCABULARY; }

Vocabulary LoadVocabulary(const StitchConfig& config) {
  return Vocabulary::Load(config.vocabulary.empty() ? DefaultVocabularyPath() : config.vocabulary);
}

void SaveStitchConfig(const StitchConfig& config, const std::string& path) {
  std::ofstream out(path);
  if (!out) throw Error(path + ": cannot write");
  out << "# stitch configuration (resolved: every setting, defaults included)\n" << DumpOptions(config);
  if (!out) throw Error(path + ": write failed");
}

}  // namespace stitch
