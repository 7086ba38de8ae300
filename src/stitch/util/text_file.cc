#include "stitch/util/text_file.h"

#include <fstream>

#include "stitch/util/error.h"

namespace stitch {

void ForEachDataLine(const std::string& path, const std::function<void(const std::string&, int)>& on_line,
                     const std::string& open_hint) {
  std::ifstream in(path);
  if (!in) throw Error(path + ": cannot open" + open_hint);
  std::string line;
  int line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const auto first = line.find_first_not_of(" \t");
    if (first == std::string::npos || line[first] == '#') continue;
    on_line(line, line_number);
  }
}

}  // namespace stitch
