#include "stitch/io/ply.h"

#include <cstring>
#include <fstream>
#include <sstream>

#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace stitch {

void WritePly(const std::string& path, const std::vector<ColouredPoint>& points, const std::string& frame) {
  std::ostringstream out(std::ios::binary);
  out << "ply\nformat binary_little_endian 1.0\ncomment written by stitch\n";
  if (!frame.empty()) out << "comment frame: " << frame << "\n";  // one line: the frame texts hold no newline
  out << "element vertex " << points.size()
      << "\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\n"
         "property uchar green\nproperty uchar blue\nend_header\n";
  for (const auto& p : points) {
    // x86 and ARM are little-endian, as the header states.
    out.write(reinterpret_cast<const char*>(p.position.data()), 3 * sizeof(float));
    const uint8_t rgb[3] = {p.red, p.green, p.blue};
    out.write(reinterpret_cast<const char*>(rgb), 3);
  }
  WriteFileAtomically(path, out.str());
}

std::vector<ColouredPoint> ReadPly(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(path + ": cannot open");
  std::string line;
  size_t count = 0;
  bool binary = false;
  while (std::getline(in, line)) {
    if (line.rfind("element vertex ", 0) == 0) count = std::stoul(line.substr(15));
    if (line == "format binary_little_endian 1.0") binary = true;
    if (line == "end_header") break;
  }
  if (!binary) throw Error(path + ": not a binary little-endian PLY written by stitch");
  std::vector<ColouredPoint> points(count);
  for (auto& p : points) {
    in.read(reinterpret_cast<char*>(p.position.data()), 3 * sizeof(float));
    uint8_t rgb[3];
    in.read(reinterpret_cast<char*>(rgb), 3);
    p.red = rgb[0];
    p.green = rgb[1];
    p.blue = rgb[2];
  }
  if (!in) throw Error(path + ": truncated");
  return points;
}

}  // namespace stitch
