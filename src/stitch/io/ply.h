#pragma once
// Point clouds as PLY (binary little-endian: float x y z, uchar red green blue), readable by
// MeshLab, CloudCompare and Open3D.

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace stitch {

struct ColouredPoint {
  Eigen::Vector3f position;
  uint8_t red = 200, green = 200, blue = 200;
};

// `frame`, when given, goes into the header as "comment frame: ..." (output_frames.h).
void WritePly(const std::string& path, const std::vector<ColouredPoint>& points, const std::string& frame = "");
// Reads what WritePly writes (for tests and tools); throws stitch::Error on anything else.
std::vector<ColouredPoint> ReadPly(const std::string& path);

}  // namespace stitch
