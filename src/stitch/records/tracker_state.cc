#include "stitch/records/tracker_state.h"

#include <filesystem>
#include <fstream>

#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace stitch {

int ReadNextSubmapNumber(const std::string& path) {
  if (!std::filesystem::exists(path)) return 0;
  std::ifstream in(path);
  std::string key;
  int number = 0;
  if (!(in >> key >> number) || key != "next_submap_number" || number < 1 || number > 65535) {
    throw Error(path + ": not a tracker state file (expected 'next_submap_number N' with N in 1..65535)");
  }
  return number;
}

void WriteNextSubmapNumber(const std::string& path, int number) {
  WriteFileAtomically(path, "next_submap_number " + std::to_string(number) + "\n");
}

}  // namespace stitch
