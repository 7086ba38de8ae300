#include "stitch/io/image_file.h"

#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace stitch {

void WritePng(const std::string& path, const cv::Mat& image) {
  std::vector<uchar> bytes;
  if (image.empty() || !cv::imencode(".png", image, bytes)) throw Error(path + ": cannot encode the image as PNG");
  WriteFileAtomically(path, std::string(bytes.begin(), bytes.end()));
}

}  // namespace stitch
