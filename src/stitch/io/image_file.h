#pragma once
// Pictures written by stitch (plots, the submap graph, rendered frames).

#include <string>

#include <opencv2/core.hpp>

namespace stitch {

// Encodes `image` as PNG and replaces the file at `path` with it as one act
// (WriteFileAtomically). Throws stitch::Error naming the file when it cannot be encoded or
// written (a full disk among them: cv::imwrite can leave a cut file and still say it wrote).
void WritePng(const std::string& path, const cv::Mat& image);

}  // namespace stitch
