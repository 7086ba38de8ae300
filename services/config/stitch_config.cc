#include "services/config/stitch_config.h"

#include <filesystem>
#include <fstream>

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

void SaveStitchConfig(const StitchConfig& config, const std::string& path) {
  std::ofstream out(path);
  if (!out) throw Error(path + ": cannot write");
  out << "# stitch configuration (resolved: every setting, defaults included)\n" << DumpOptions(config);
  if (!out) throw Error(path + ": write failed");
}

}  // namespace stitch
