#include "stitch/util/options.h"

#include <filesystem>

namespace stitch {

YAML::Node LoadYamlFile(const std::string& path) {
  if (!std::filesystem::exists(path)) throw Error(path + ": no such file");
  try {
    return YAML::LoadFile(path);
  } catch (const YAML::ParserException& e) {
    throw Error(path + ": not valid YAML (line " + std::to_string(e.mark.line + 1) + ": " + e.msg + ")");
  } catch (const YAML::Exception& e) {
    throw Error(path + ": cannot read (" + std::string(e.what()) + ")");
  }
}

}  // namespace stitch
