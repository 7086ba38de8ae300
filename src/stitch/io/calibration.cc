#include "stitch/io/calibration.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <optional>
#include <sstream>

#include <yaml-cpp/yaml.h>
#include <opencv2/core.hpp>

#include "stitch/util/error.h"
#include "stitch/util/options.h"
#include "stitch/util/text_file.h"

namespace stitch {
namespace {

std::vector<double> NumberList(const YAML::Node& node, const std::string& what, const std::string& path) {
  try {
    return node.as<std::vector<double>>();
  } catch (const YAML::Exception&) {
    throw Error(path + ": " + what + " is not a list of numbers");
  }
}

Camera FinishCamera(CameraModel model, int file_width, int file_height, const std::vector<double>& params,
                    int image_width, int image_height, const std::string& path) {
  int width = file_width;
  int height = file_height;
  if (width > 0 && height > 0) {
    if (image_width > 0 && image_height > 0 && (width != image_width || height != image_height)) {
      throw Error(Str() << path << ": calibration is for " << width << "x" << height << " images but the images are "
                        << image_width << "x" << image_height << "; use the calibration of this camera and resolution");
    }
  } else if (image_width > 0 && image_height > 0) {
    width = image_width;
    height = image_height;
  } else {
    throw Error(path + ": the file does not state the image size (Camera.width, Camera.height)");
  }
  try {
    return Camera(model, width, height, params);
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
}

// An ORB-SLAM2 / ORB-SLAM3 settings file, read as ORB-SLAM reads it: with OpenCV's FileStorage,
// which accepts what YAML parsers refuse (`Viewer.PointSize:2`, no space after the colon).
class OrbSlamSettings {
 public:
  // Empty when the file is no FileStorage YAML or names no camera (Camera.fx or Camera1.fx).
  static std::optional<OrbSlamSettings> Read(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    // FileStorage wants its header; ORB-SLAM's files have it, hand-written copies often not.
    if (text.rfind("%YAML", 0) != 0) text = "%YAML:1.0\n" + text;
    OrbSlamSettings settings(path);
    try {
      if (!settings.storage_.open(text, cv::FileStorage::READ | cv::FileStorage::MEMORY | cv::FileStorage::FORMAT_YAML))
        return std::nullopt;
    } catch (const cv::Exception&) {
      return std::nullopt;
    }
    if (settings.Has("Camera.fx"))
      settings.prefix_ = "Camera.";
    else if (settings.Has("Camera1.fx"))
      settings.prefix_ = "Camera1.";
    else
      return std::nullopt;
    return settings;
  }

  // "Camera." (ORB-SLAM2) or "Camera1." (ORB-SLAM3): the prefix of the intrinsics.
  const std::string& prefix() const { return prefix_; }
  bool Has(const std::string& key) const { return !storage_[key].empty(); }
  double Number(const std::string& key) const {
    const cv::FileNode node = storage_[key];
    if (node.empty()) throw Error(path_ + ": missing " + key);
    if (!node.isReal() && !node.isInt()) throw Error(path_ + ": " + key + " is not a number");
    return static_cast<double>(node);
  }
  double NumberOr(const std::string& key, double otherwise) const { return Has(key) ? Number(key) : otherwise; }
  std::string Text(const std::string& key, const std::string& otherwise) const {
    const cv::FileNode node = storage_[key];
    if (node.empty()) return otherwise;
    if (!node.isString()) throw Error(path_ + ": " + key + " is not text");
    return static_cast<std::string>(node);
  }

 private:
  explicit OrbSlamSettings(std::string path) : path_(std::move(path)) {}
  std::string path_;
  std::string prefix_;
  cv::FileStorage storage_;
};

Camera ReadOrbSlamSettings(const OrbSlamSettings& settings, int image_width, int image_height,
                           const std::string& path) {
  const std::string type = settings.Text("Camera.type", "PinHole");
  const std::string& prefix = settings.prefix();
  const auto get = [&](const std::string& name) { return settings.Number(prefix + name); };
  const auto opt = [&](const std::string& name) { return settings.NumberOr(prefix + name, 0.0); };
  const int width = static_cast<int>(settings.NumberOr("Camera.width", opt("width")));
  const int height = static_cast<int>(settings.NumberOr("Camera.height", opt("height")));
  if (type == "PinHole" || type == "Pinhole" || type == "pinhole") {
    return FinishCamera(
        CameraModel::kPinholeRadTan, width, height,
        {get("fx"), get("fy"), get("cx"), get("cy"), opt("k1"), opt("k2"), opt("p1"), opt("p2"), opt("k3")},
        image_width, image_height, path);
  }
  if (type == "KannalaBrandt8" || type == "Fisheye" || type == "fisheye") {
    return FinishCamera(CameraModel::kFisheye, width, height,
                        {get("fx"), get("fy"), get("cx"), get("cy"), opt("k1"), opt("k2"), opt("k3"), opt("k4")},
                        image_width, image_height, path);
  }
  throw Error(path + ": Camera.type '" + type + "' is not supported (use PinHole or KannalaBrandt8)");
}

// EuRoC / Kalibr sensor.yaml.
Camera ReadSensorYaml(const YAML::Node& root, int image_width, int image_height, const std::string& path) {
  const std::vector<double> k = NumberList(root["intrinsics"], "intrinsics", path);
  if (k.size() != 4) throw Error(path + ": intrinsics must be [fu, fv, cu, cv]");
  std::vector<double> d;
  if (root["distortion_coefficients"]) {
    d = NumberList(root["distortion_coefficients"], "distortion_coefficients", path);
  }
  int width = 0, height = 0;
  if (root["resolution"]) {
    const auto r = NumberList(root["resolution"], "resolution", path);
    if (r.size() != 2) throw Error(path + ": resolution must be [width, height]");
    width = static_cast<int>(r[0]);
    height = static_cast<int>(r[1]);
  }
  const std::string model = root["distortion_model"] ? root["distortion_model"].as<std::string>() : "radial-tangential";
  if (root["camera_model"] && root["camera_model"].as<std::string>() != "pinhole") {
    throw Error(path + ": camera_model '" + root["camera_model"].as<std::string>() +
                "' is not supported (pinhole only)");
  }
  if (model == "radial-tangential" || model == "radtan" || model == "plumb_bob") {
    if (d.size() < 4 || d.size() > 5) {
      throw Error(path + ": radial-tangential needs 4 or 5 distortion_coefficients (k1 k2 p1 p2 [k3])");
    }
    return FinishCamera(CameraModel::kPinholeRadTan, width, height,
                        {k[0], k[1], k[2], k[3], d[0], d[1], d[2], d[3], d.size() == 5 ? d[4] : 0.0}, image_width,
                        image_height, path);
  }
  if (model == "equidistant") {
    if (d.size() != 4) throw Error(path + ": equidistant needs 4 distortion_coefficients");
    return FinishCamera(CameraModel::kFisheye, width, height, {k[0], k[1], k[2], k[3], d[0], d[1], d[2], d[3]},
                        image_width, image_height, path);
  }
  throw Error(path + ": distortion_model '" + model + "' is not supported (radial-tangential or equidistant)");
}

// KITTI odometry calib.txt: "P0: fx 0 cx 0 0 fy cy 0 0 0 1 0".
Camera ReadKittiCalib(const std::string& path, int image_width, int image_height) {
  std::ifstream in(path);
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("P0:", 0) != 0) continue;
    std::istringstream values(line.substr(3));
    double p[12];
    for (double& v : p) values >> v;
    if (!values) throw Error(path + ": P0 needs 12 numbers");
    return FinishCamera(CameraModel::kPinholeRadTan, 0, 0, {p[0], p[5], p[2], p[6], 0, 0, 0, 0, 0}, image_width,
                        image_height, path);
  }
  throw Error(path + ": no 'P0:' line (KITTI calib.txt)");
}

}  // namespace

Camera LoadCalibration(const std::string& path, int image_width, int image_height) {
  if (!std::filesystem::exists(path)) throw Error(path + ": calibration file not found");
  if (std::filesystem::path(path).extension() == ".txt") {
    return ReadKittiCalib(path, image_width, image_height);
  }
  if (const auto settings = OrbSlamSettings::Read(path)) {
    return ReadOrbSlamSettings(*settings, image_width, image_height, path);
  }
  const YAML::Node root = LoadYamlFile(path);
  if (!root.IsMap()) throw Error(path + ": expected a YAML map of calibration keys");
  if (root["intrinsics"]) return ReadSensorYaml(root, image_width, image_height, path);
  throw Error(path +
              ": not a calibration file stitch knows (expected ORB-SLAM settings with Camera.fx, "
              "or a EuRoC/Kalibr sensor.yaml with intrinsics)");
}

std::map<std::string, double> ReadOrbExtractorSettings(const std::string& path) {
  std::map<std::string, double> stated;
  const auto settings = OrbSlamSettings::Read(path);
  if (!settings) return stated;
  for (const char* name : {"nFeatures", "scaleFactor", "nLevels", "iniThFAST", "minThFAST"}) {
    const std::string key = std::string("ORBextractor.") + name;
    if (settings->Has(key)) stated[name] = settings->Number(key);
  }
  return stated;
}

std::optional<double> ReadLineDelayUs(const std::string& path) {
  const auto settings = OrbSlamSettings::Read(path);
  if (!settings || !settings->Has("Camera.line_delay_us")) return std::nullopt;
  return settings->Number("Camera.line_delay_us");
}

std::string CalibrationDoubts(const Camera& camera) {
  constexpr double kFarFromCentre = 0.2;  // of the image's width or height
  const double off_x = std::abs(camera.cx() - 0.5 * camera.width()) / camera.width();
  const double off_y = std::abs(camera.cy() - 0.5 * camera.height()) / camera.height();
  if (off_x <= kFarFromCentre && off_y <= kFarFromCentre) return "";
  std::ostringstream text;
  text.precision(4);
  text << "the calibration's principal point (" << camera.cx() << ", " << camera.cy()
       << ") is far from the centre of the " << camera.width() << "x" << camera.height() << " image ("
       << 0.5 * camera.width() << ", " << 0.5 * camera.height()
       << "): is it this camera's calibration? (a lens's is within a few percent of the centre)";
  return text.str();
}

void SaveCalibration(const Camera& camera, const std::string& path, double line_delay_us) {
  std::ostringstream out;
  out.precision(12);
  const auto p = camera.params();
  out << "%YAML:1.0\n# Written by stitch. ORB-SLAM-style settings.\n";
  if (camera.model() == CameraModel::kPinholeRadTan) {
    out << "Camera.type: \"PinHole\"\n";
  } else {
    out << "Camera.type: \"KannalaBrandt8\"\n";
  }
  out << "Camera.fx: " << p[0] << "\nCamera.fy: " << p[1] << "\nCamera.cx: " << p[2] << "\nCamera.cy: " << p[3] << "\n";
  if (camera.model() == CameraModel::kPinholeRadTan) {
    out << "Camera.k1: " << p[4] << "\nCamera.k2: " << p[5] << "\nCamera.p1: " << p[6] << "\nCamera.p2: " << p[7]
        << "\nCamera.k3: " << p[8] << "\n";
  } else {
    out << "Camera.k1: " << p[4] << "\nCamera.k2: " << p[5] << "\nCamera.k3: " << p[6] << "\nCamera.k4: " << p[7]
        << "\n";
  }
  out << "Camera.width: " << camera.width() << "\nCamera.height: " << camera.height() << "\n";
  if (line_delay_us > 0)
    out << "# Rolling shutter: readout delay from one row to the next.\nCamera.line_delay_us: " << line_delay_us
        << "\n";
  WriteFileAtomically(path, out.str());
}

}  // namespace stitch
