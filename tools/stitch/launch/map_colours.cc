#include "tools/stitch/launch/map_colours.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>
#include <regex>
#include <unordered_map>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>

#include "stitch/io/calibration.h"
#include "stitch/io/image_sequence.h"
#include "stitch/io/ply.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

// Each point's first sight: image id -> (feature, point index).
std::map<int, std::vector<std::pair<int, int>>> FirstSights(const ColmapModel& model) {
  std::map<int, std::vector<std::pair<int, int>>> first_sight;
  for (size_t p = 0; p < model.points.size(); ++p) {
    const auto& [image_id, feature] = model.points[p].track.front();
    first_sight[image_id].push_back({feature, static_cast<int>(p)});
  }
  return first_sight;
}

// The points first seen in `image` take their pixel's colour in `colour` (BGR), the image's
// features at its size.
void ColourFromImage(const ColmapImage& image, const std::vector<std::pair<int, int>>& sights, const cv::Mat& colour,
                     ColmapModel* model) {
  for (const auto& [feature, p] : sights) {
    const Eigen::Vector2d& f = image.features[feature];
    const int x = std::clamp(static_cast<int>(std::lround(f.x())), 0, colour.cols - 1);
    const int y = std::clamp(static_cast<int>(std::lround(f.y())), 0, colour.rows - 1);
    const cv::Vec3b bgr = colour.at<cv::Vec3b>(y, x);
    model->points[p].rgb = {bgr[2], bgr[1], bgr[0]};
  }
}

}  // namespace

int FrameOfModelImage(const ColmapImage& image) {
  static const std::regex placeholder("agent([0-9]+)-frame([0-9]+)");
  std::smatch match;
  if (!std::regex_match(image.name, match, placeholder)) {
    throw Error("image " + std::to_string(image.id) + " is named '" + image.name +
                "', not agentA-frameNNNNNN as the merger names them");
  }
  if (std::stoi(match[1]) != 0) {
    throw Error("the map holds keyframes of aircraft " + match[1].str() +
                "; --images names one aircraft's images (export a single aircraft's run)");
  }
  return std::stoi(match[2]);
}

ColmapModel ModelOnImages(ColmapModel model, const std::string& images, int start_frame, const std::string& scratch) {
  // The dataset's own reader lists its images in play order; the model's camera stands in for a
  // calibration (the run's; its size is checked against the images below), which an image folder may not have.
  if (model.cameras.size() != 1) {
    throw Error("the map holds the images of " + std::to_string(model.cameras.size()) +
                " cameras; --images names one aircraft's images (export a single aircraft's run)");
  }
  const int camera_id = model.cameras.begin()->first;
  const Camera camera = model.cameras.begin()->second;
  SaveCalibration(camera, scratch);
  SequenceOptions options;
  options.calibration_path = scratch;
  options.start_frame = start_frame;
  const auto sequence = OpenDataset(images, options);
  const auto first_sight = FirstSights(model);
  std::vector<std::string> paths;  // per model image
  for (ColmapImage& image : model.images) {
    const int frame = FrameOfModelImage(image);
    const std::string path = sequence->image_path(frame);
    if (path.empty()) {
      throw Error(images + " has no image file for frame " + std::to_string(frame) +
                  (sequence->size() <= frame ? " (it holds " + std::to_string(sequence->size()) + " frames)"
                                             : std::string(" (a video: write its frames as images first)")));
    }
    image.name = fs::relative(path, images).generic_string();
    paths.push_back(path);
  }
  // A run works at a reduced size where the camera's frames are larger (ingest.max_working_pixels):
  // the model goes back to the images' size.
  for (const std::string& path : paths) {
    const cv::Mat first = cv::imread(path, cv::IMREAD_GRAYSCALE);
    if (first.empty()) continue;
    if (first.cols != camera.width() || first.rows != camera.height()) {
      STITCH_LOG(INFO) << "the run worked at " << camera.width() << "x" << camera.height()
                       << "; the model is scaled to the images' " << first.cols << "x" << first.rows;
      model = ResizeColmapModel(std::move(model), camera_id, first.cols, first.rows);
    }
    break;
  }
  for (size_t i = 0; i < model.images.size(); ++i) {
    const ColmapImage& image = model.images[i];
    const auto sights = first_sight.find(image.id);
    if (sights == first_sight.end()) continue;
    const cv::Mat colour = cv::imread(paths[i], cv::IMREAD_COLOR);
    if (colour.empty()) continue;  // grey stays
    ColourFromImage(image, sights->second, colour, &model);
  }
  return model;
}

ColmapModel ColourFromVideo(ColmapModel model, const std::string& video, int start_frame) {
  if (model.cameras.size() != 1) {
    throw Error("the map holds the images of " + std::to_string(model.cameras.size()) + " cameras, not one video's");
  }
  cv::VideoCapture capture(video);
  if (!capture.isOpened()) throw Error(video + ": cannot be decoded here");
  // The run may have worked at a reduced size: the model goes to the clip's.
  const int camera_id = model.cameras.begin()->first;
  const Camera camera = model.cameras.begin()->second;
  const int width = static_cast<int>(capture.get(cv::CAP_PROP_FRAME_WIDTH));
  const int height = static_cast<int>(capture.get(cv::CAP_PROP_FRAME_HEIGHT));
  if (width > 0 && height > 0 && (width != camera.width() || height != camera.height())) {
    model = ResizeColmapModel(std::move(model), camera_id, width, height);
  }
  const auto first_sight = FirstSights(model);
  std::map<int, const ColmapImage*> image_at;  // by the video's frame index
  for (const ColmapImage& image : model.images) {
    if (first_sight.count(image.id)) image_at[start_frame + FrameOfModelImage(image)] = &image;
  }
  cv::Mat frame;
  int index = 0;
  auto next = image_at.begin();
  while (next != image_at.end() && capture.read(frame)) {
    if (index++ != next->first) continue;
    if (frame.type() == CV_8UC3) ColourFromImage(*next->second, first_sight.at(next->second->id), frame, &model);
    ++next;
  }
  if (next != image_at.end()) {
    throw Error(video + " ended at frame " + std::to_string(index) + ", before keyframe " +
                std::to_string(next->first));
  }
  return model;
}

int ColourCloudFromModel(const std::string& ply_path, const ColmapModel& coloured, const std::string& frame) {
  // The cloud and the model hold the same points of the same map: the same positions, to the bit
  // once in the cloud's single precision.
  const auto key = [](const Eigen::Vector3f& p) {
    uint32_t bits[3];
    std::memcpy(bits, p.data(), sizeof(bits));
    return (uint64_t{bits[0]} * 0x9E3779B97F4A7C15ull) ^ (uint64_t{bits[1]} * 0xC2B2AE3D27D4EB4Full) ^ bits[2];
  };
  std::unordered_multimap<uint64_t, const ColmapPoint*> by_position;
  for (const ColmapPoint& point : coloured.points) {
    by_position.emplace(key(point.position.cast<float>()), &point);
  }
  std::vector<ColouredPoint> cloud = ReadPly(ply_path);
  int taken = 0;
  for (ColouredPoint& p : cloud) {
    const ColmapPoint* match = nullptr;
    const auto [begin, end] = by_position.equal_range(key(p.position));
    for (auto it = begin; it != end && !match; ++it) {
      if (it->second->position.cast<float>() == p.position) match = it->second;
    }
    p.red = p.green = p.blue = 128;
    if (!match) continue;
    p.red = match->rgb[0];
    p.green = match->rgb[1];
    p.blue = match->rgb[2];
    ++taken;
  }
  WritePly(ply_path, cloud, frame);
  return taken;
}

}  // namespace stitch
