#include "stitch/io/colmap_model.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

// The lines that are not comments; empty ones too when `keep_empty` (images.txt gives an image
// without features an empty second line).
std::vector<std::string> DataLines(const std::string& path, bool keep_empty = false) {
  std::vector<std::string> lines;
  std::ifstream in(path);
  if (!in) throw Error(path + ": cannot open");
  for (std::string line; std::getline(in, line);) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if ((line.empty() && !keep_empty) || (!line.empty() && line[0] == '#')) continue;
    lines.push_back(line);
  }
  return lines;
}

}  // namespace

ColmapCameraModel ColmapCameraModelOf(const Camera& camera) {
  const std::vector<double> p = camera.params();
  const double cx = p[2] + kColmapHalfPixel, cy = p[3] + kColmapHalfPixel;
  if (camera.model() == CameraModel::kFisheye)
    return {"OPENCV_FISHEYE", 5, {p[0], p[1], cx, cy, p[4], p[5], p[6], p[7]}};
  if (!camera.HasDistortion()) return {"PINHOLE", 1, {p[0], p[1], cx, cy}};
  if (p[8] == 0) return {"OPENCV", 4, {p[0], p[1], cx, cy, p[4], p[5], p[6], p[7]}};
  // k3: COLMAP's full OpenCV model (its rational k4..k6 zero)
  return {"FULL_OPENCV", 6, {p[0], p[1], cx, cy, p[4], p[5], p[6], p[7], p[8], 0, 0, 0}};
}

std::string ColmapCameraLine(const Camera& camera, int id) {
  const ColmapCameraModel colmap = ColmapCameraModelOf(camera);
  std::ostringstream line;
  line.precision(17);
  line << id << " " << colmap.name << " " << camera.width() << " " << camera.height();
  for (double v : colmap.params) line << " " << v;
  return line.str();
}

void WriteColmapModel(const ColmapModel& model, const std::string& dir) {
  fs::create_directories(dir);
  {
    std::ostringstream out;
    out << "# Camera list with one line of data per camera:\n"
           "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n# Number of cameras: "
        << model.cameras.size() << "\n";
    for (const auto& [id, camera] : model.cameras) out << ColmapCameraLine(camera, id) << "\n";
    WriteFileAtomically((fs::path(dir) / "cameras.txt").string(), out.str());
  }
  {
    std::ostringstream out;
    out.precision(17);
    size_t observations = 0;
    for (const ColmapImage& image : model.images) {
      for (int64_t id : image.point_ids) observations += id >= 0;
    }
    out << "# Image list with two lines of data per image:\n"
           "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
           "#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
        << "# Number of images: " << model.images.size() << ", mean observations per image: "
        << (model.images.empty() ? 0.0 : static_cast<double>(observations) / model.images.size()) << "\n";
    for (const ColmapImage& image : model.images) {
      if (image.name.empty() || image.name.find_first_of(" \t\n") != std::string::npos) {
        throw Error("COLMAP image " + std::to_string(image.id) + ": its name must be one word, not '" + image.name +
                    "'");
      }
      if (image.features.size() != image.point_ids.size()) {
        throw Error("COLMAP image " + std::to_string(image.id) + ": one point id per feature");
      }
      if (!model.cameras.count(image.camera_id)) {
        throw Error("COLMAP image " + std::to_string(image.id) + ": no camera " + std::to_string(image.camera_id));
      }
      const Eigen::Quaterniond& q = image.cam_from_world.rotation;
      const Eigen::Vector3d& t = image.cam_from_world.translation;
      out << image.id << " " << q.w() << " " << q.x() << " " << q.y() << " " << q.z() << " " << t.x() << " " << t.y()
          << " " << t.z() << " " << image.camera_id << " " << image.name << "\n";
      for (size_t i = 0; i < image.features.size(); ++i) {
        out << (i ? " " : "") << image.features[i].x() + kColmapHalfPixel << " "
            << image.features[i].y() + kColmapHalfPixel << " " << image.point_ids[i];
      }
      out << "\n";
    }
    WriteFileAtomically((fs::path(dir) / "images.txt").string(), out.str());
  }
  {
    std::ostringstream out;
    out.precision(17);
    out << "# 3D point list with one line of data per point:\n"
           "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
        << "# Number of points: " << model.points.size() << "\n";
    for (const ColmapPoint& point : model.points) {
      out << point.id << " " << point.position.x() << " " << point.position.y() << " " << point.position.z() << " "
          << int(point.rgb[0]) << " " << int(point.rgb[1]) << " " << int(point.rgb[2]) << " " << point.error_px;
      for (const auto& [image, feature] : point.track) out << " " << image << " " << feature;
      out << "\n";
    }
    WriteFileAtomically((fs::path(dir) / "points3D.txt").string(), out.str());
  }
}

ColmapModel ReadColmapModel(const std::string& dir) {
  ColmapModel model;
  const std::string cameras = (fs::path(dir) / "cameras.txt").string();
  const std::vector<std::string> camera_lines = DataLines(cameras);
  if (camera_lines.empty()) throw Error(cameras + ": no camera");
  for (const std::string& camera_line : camera_lines) {
    std::istringstream fields(camera_line);
    int id = 0, width = 0, height = 0;
    std::string name;
    if (!(fields >> id >> name >> width >> height)) {
      throw Error(cameras + ": '" + camera_line.substr(0, 60) + "' is not 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]'");
    }
    std::vector<double> p;
    for (double v; fields >> v;) p.push_back(v);
    const auto need = [&](size_t n) {
      if (p.size() != n) throw Error(cameras + ": " + name + " takes " + std::to_string(n) + " parameters");
    };
    if (name == "PINHOLE") {
      need(4);
      p.resize(9, 0.0);
    } else if (name == "OPENCV") {
      need(8);
      p.push_back(0.0);
    } else if (name == "FULL_OPENCV") {
      need(12);
      if (p[9] != 0 || p[10] != 0 || p[11] != 0) throw Error(cameras + ": rational distortion (k4..k6) is not read");
      p.resize(9);
    } else if (name == "OPENCV_FISHEYE") {
      need(8);
    } else {
      throw Error(cameras + ": camera model '" + name + "' is not one stitch reads");
    }
    p[2] -= kColmapHalfPixel;
    p[3] -= kColmapHalfPixel;
    try {
      const Camera camera(name == "OPENCV_FISHEYE" ? CameraModel::kFisheye : CameraModel::kPinholeRadTan, width, height,
                          p);
      if (!model.cameras.emplace(id, camera).second) throw Error("camera " + std::to_string(id) + " twice");
    } catch (const Error& e) {
      throw Error(cameras + ": " + e.what());
    }
  }
  const std::string images = (fs::path(dir) / "images.txt").string();
  std::vector<std::string> image_lines = DataLines(images, /*keep_empty=*/true);
  while (!image_lines.empty() && image_lines.back().empty() && image_lines.size() % 2 == 1) image_lines.pop_back();
  if (image_lines.size() % 2 == 1) image_lines.emplace_back();  // the last image's features left out
  std::map<int, size_t> image_index;
  for (size_t i = 0; i < image_lines.size(); i += 2) {
    const std::string where = images + ": image line " + std::to_string(i / 2 + 1);
    std::istringstream fields(image_lines[i]);
    ColmapImage image;
    double q[4], t[3];
    std::string extra;
    if (!(fields >> image.id >> q[0] >> q[1] >> q[2] >> q[3] >> t[0] >> t[1] >> t[2] >> image.camera_id >>
          image.name) ||
        (fields >> extra)) {
      throw Error(where + " is not 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'");
    }
    if (!model.cameras.count(image.camera_id)) {
      throw Error(where + " names camera " + std::to_string(image.camera_id) + ", which " + cameras + " does not hold");
    }
    image.cam_from_world =
        Rigid3d(Eigen::Quaterniond(q[0], q[1], q[2], q[3]).normalized(), Eigen::Vector3d(t[0], t[1], t[2]));
    std::istringstream features(image_lines[i + 1]);
    std::vector<std::string> words;
    for (std::string w; features >> w;) words.push_back(w);
    if (words.size() % 3 != 0) throw Error(where + ": its features are not triples 'X Y POINT3D_ID'");
    for (size_t k = 0; k < words.size(); k += 3) {
      try {
        image.features.emplace_back(std::stod(words[k]) - kColmapHalfPixel, std::stod(words[k + 1]) - kColmapHalfPixel);
        image.point_ids.push_back(std::stoll(words[k + 2]));
      } catch (const std::exception&) {
        throw Error(where + ": a feature is not 'X Y POINT3D_ID'");
      }
    }
    if (!image_index.emplace(image.id, model.images.size()).second) {
      throw Error(images + ": image " + std::to_string(image.id) + " twice");
    }
    model.images.push_back(std::move(image));
  }
  const std::string points = (fs::path(dir) / "points3D.txt").string();
  for (const std::string& line : DataLines(points)) {
    std::istringstream fields(line);
    ColmapPoint point;
    int rgb[3];
    if (!(fields >> point.id >> point.position.x() >> point.position.y() >> point.position.z() >> rgb[0] >> rgb[1] >>
          rgb[2] >> point.error_px)) {
      throw Error(points + ": '" + line.substr(0, 60) + "' is not a point");
    }
    for (int k = 0; k < 3; ++k) point.rgb[k] = static_cast<uint8_t>(rgb[k]);
    for (int image, feature; fields >> image >> feature;) {
      const auto found = image_index.find(image);
      if (found == image_index.end() || feature < 0 ||
          feature >= static_cast<int>(model.images[found->second].features.size())) {
        throw Error(points + ": point " + std::to_string(point.id) + " names feature " + std::to_string(feature) +
                    " of image " + std::to_string(image) + ", which is not there");
      }
      point.track.push_back({image, feature});
    }
    model.points.push_back(std::move(point));
  }
  return model;
}

namespace {

// Each observation's reprojection error, pixels, by point in the model's order. Behind the
// camera: an error as large as the image, so that it shows.
std::vector<std::vector<double>> ReprojectionErrors(const ColmapModel& model) {
  std::map<int, const ColmapImage*> by_id;
  for (const ColmapImage& image : model.images) by_id[image.id] = &image;
  std::vector<std::vector<double>> errors;
  for (const ColmapPoint& point : model.points) {
    std::vector<double>& track = errors.emplace_back();
    for (const auto& [image_id, feature] : point.track) {
      const ColmapImage& image = *by_id.at(image_id);
      const Camera& camera = model.cameras.at(image.camera_id);
      const auto projected = camera.Project(image.cam_from_world * point.position);
      track.push_back(projected ? (*projected - image.features.at(feature)).norm()
                                : static_cast<double>(camera.width() + camera.height()));
    }
  }
  return errors;
}

}  // namespace

double ReprojectionRms(const ColmapModel& model) {
  double sum = 0;
  size_t count = 0;
  for (const auto& track : ReprojectionErrors(model)) {
    for (double e : track) sum += e * e;
    count += track.size();
  }
  return count ? std::sqrt(sum / count) : 0.0;
}

void SetReprojectionErrors(ColmapModel* model) {
  const auto errors = ReprojectionErrors(*model);
  for (size_t i = 0; i < model->points.size(); ++i) {
    double sum = 0;
    for (double e : errors[i]) sum += e;
    model->points[i].error_px = errors[i].empty() ? 0 : sum / errors[i].size();
  }
}

ColmapModel ResizeColmapModel(ColmapModel model, int camera_id, int width, int height) {
  Camera& camera = model.cameras.at(camera_id);
  const double sx = static_cast<double>(width) / camera.width();
  const double sy = static_cast<double>(height) / camera.height();
  camera = camera.Resized(width, height);
  for (ColmapImage& image : model.images) {
    if (image.camera_id != camera_id) continue;
    for (Eigen::Vector2d& f : image.features) f = {(f.x() + 0.5) * sx - 0.5, (f.y() + 0.5) * sy - 0.5};
  }
  SetReprojectionErrors(&model);
  return model;
}

}  // namespace stitch
