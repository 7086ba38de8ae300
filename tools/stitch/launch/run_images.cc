#include "tools/stitch/launch/run_images.h"

#include <algorithm>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>

#include "stitch/util/error.h"

namespace stitch {
namespace {

cv::Mat ReadImageFile(const std::string& path) {
  cv::Mat image = cv::imread(path, cv::IMREAD_COLOR);
  if (image.empty()) throw Error(path + ": not a readable image");
  return image;
}

}  // namespace

void ReadRunImages(const SourceSpec& spec, std::vector<int> frames,
                   const std::function<void(int frame, const cv::Mat& image)>& take) {
  std::sort(frames.begin(), frames.end());
  frames.erase(std::unique(frames.begin(), frames.end()), frames.end());
  if (frames.empty()) return;
  if (frames.front() < 0) throw Error("frame " + std::to_string(frames.front()) + " is no frame of the run");
  if (!spec.live_uri.empty()) throw Error("a live camera's frames are gone once flown");
  if (spec.synthetic_source()) {
    const auto flight = OpenSyntheticFlight(spec);
    for (const int frame : frames) {
      const int index = spec.start_frame + frame;
      if (index >= flight->size()) {
        throw Error("the synthetic flight has " + std::to_string(flight->size()) + " frames, not frame " +
                    std::to_string(index));
      }
      take(frame, flight->RenderFrame(index));
    }
    return;
  }
  const std::string kind = DetectDatasetKind(spec.dataset_path);
  if (kind == "folder") {
    const std::vector<ImageEntry> images = FolderImageTimes(spec.dataset_path);
    for (const int frame : frames) {
      const size_t index = static_cast<size_t>(spec.start_frame) + frame;
      if (index >= images.size()) {
        throw Error(spec.dataset_path + " holds " + std::to_string(images.size()) + " images, not frame " +
                    std::to_string(index));
      }
      take(frame, ReadImageFile(images[index].path));
    }
    return;
  }
  if (kind == "video") {
    cv::VideoCapture capture(spec.dataset_path);
    if (!capture.isOpened()) throw Error(spec.dataset_path + ": cannot be decoded here");
    cv::Mat image;
    int index = 0;
    for (const int frame : frames) {
      const int wanted = spec.start_frame + frame;
      while (index <= wanted) {
        if (!capture.read(image)) {
          throw Error(spec.dataset_path + " ends after " + std::to_string(index) + " frames, before frame " +
                      std::to_string(wanted));
        }
        ++index;
      }
      take(frame, image);
    }
    return;
  }
  // A dataset of its own layout: its image files where it names them, else its frames in order.
  SequenceOptions options;
  options.calibration_path = spec.calibration_path;
  options.start_frame = spec.start_frame;
  const auto sequence = OpenDataset(spec.dataset_path, options);
  SequenceFrame played;
  int next = 0;  // the sequence's next frame, when read in order
  for (const int frame : frames) {
    const std::string path = sequence->image_path(frame);
    if (!path.empty()) {
      take(frame, ReadImageFile(path));
      continue;
    }
    while (next <= frame) {
      if (!sequence->Next(&played)) {
        throw Error(spec.dataset_path + " ends before frame " + std::to_string(spec.start_frame + frame));
      }
      ++next;
    }
    if (played.image.empty()) throw Error(played.error);
    take(frame, played.image);
  }
}

}  // namespace stitch
