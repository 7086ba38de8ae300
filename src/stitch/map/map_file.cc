#include "stitch/map/map_file.h"

#include <sodium.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>

#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace stitch {
namespace {

constexpr char kMagic[8] = {'S', 'T', 'I', 'T', 'C', 'H', 'M', 'P'};
constexpr size_t kChecksumBytes = 32;
constexpr size_t kHeaderBytes = 8 + 4 + 4 + 8 + kChecksumBytes;
constexpr uint32_t kNone = 0xffffffffu;
constexpr size_t kMaxDescriptionBytes = 64 * 1024;
// Encoded sizes, for checking a count against the bytes left before anything is allocated.
constexpr size_t kCameraMinBytes = 1 + 4 + 4 + 4;
constexpr size_t kPointBytes = 3 * 8 + 32 + 3 * 8 + 4 + 4 + 4 + 4 + 4 + 4;
constexpr size_t kKeyframeMinBytes = 8 + 4 + 8 + 7 * 8 + 4 + 4;
constexpr size_t kFeatureBytes = 5 * 4 + 4 + 4 + 32;

// Little-endian whatever the host.
class Writer {
 public:
  void U8(uint8_t v) { bytes_.push_back(static_cast<char>(v)); }
  void U32(uint32_t v) {
    for (int i = 0; i < 4; ++i) U8(static_cast<uint8_t>(v >> (8 * i)));
  }
  void U64(uint64_t v) {
    for (int i = 0; i < 8; ++i) U8(static_cast<uint8_t>(v >> (8 * i)));
  }
  void I32(int32_t v) { U32(static_cast<uint32_t>(v)); }
  void I64(int64_t v) { U64(static_cast<uint64_t>(v)); }
  void F32(float v) {
    uint32_t u;
    std::memcpy(&u, &v, 4);
    U32(u);
  }
  void F64(double v) {
    uint64_t u;
    std::memcpy(&u, &v, 8);
    U64(u);
  }
  void Bytes(const void* data, size_t n) { bytes_.append(static_cast<const char*>(data), n); }
  void String(const std::string& s) {
    U32(static_cast<uint32_t>(s.size()));
    bytes_ += s;
  }
  std::string& bytes() { return bytes_; }

 private:
  std::string bytes_;
};

class Reader {
 public:
  Reader(const std::string& bytes, size_t begin, size_t end) : bytes_(bytes), at_(begin), end_(end) {}
  size_t left() const { return end_ - at_; }
  void Need(size_t n, const char* what) const {
    if (n > left()) throw Error(std::string("cut short in ") + what);
  }
  uint8_t U8(const char* what) {
    Need(1, what);
    return static_cast<uint8_t>(bytes_[at_++]);
  }
  uint32_t U32(const char* what) {
    Need(4, what);
    uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v |= static_cast<uint32_t>(static_cast<uint8_t>(bytes_[at_++])) << (8 * i);
    return v;
  }
  uint64_t U64(const char* what) {
    Need(8, what);
    uint64_t v = 0;
    for (int i = 0; i < 8; ++i) v |= static_cast<uint64_t>(static_cast<uint8_t>(bytes_[at_++])) << (8 * i);
    return v;
  }
  int32_t I32(const char* what) { return static_cast<int32_t>(U32(what)); }
  int64_t I64(const char* what) { return static_cast<int64_t>(U64(what)); }
  float F32(const char* what) {
    const uint32_t u = U32(what);
    float v;
    std::memcpy(&v, &u, 4);
    if (!std::isfinite(v)) throw Error(std::string("a number that is not finite in ") + what);
    return v;
  }
  double F64(const char* what) {
    const uint64_t u = U64(what);
    double v;
    std::memcpy(&v, &u, 8);
    if (!std::isfinite(v)) throw Error(std::string("a number that is not finite in ") + what);
    return v;
  }
  void Bytes(void* out, size_t n, const char* what) {
    Need(n, what);
    std::memcpy(out, bytes_.data() + at_, n);
    at_ += n;
  }
  // A count of elements of at least `element_bytes` each, checked against the bytes left.
  uint32_t Count(size_t element_bytes, const char* what) {
    const uint32_t n = U32(what);
    if (static_cast<uint64_t>(n) * element_bytes > left()) {
      throw Error(std::string("cut short in ") + what + ": " + std::to_string(n) + " of them cannot fit in the " +
                  std::to_string(left()) + " bytes left");
    }
    return n;
  }
  std::string String(size_t max_bytes, const char* what) {
    const uint32_t n = Count(1, what);
    if (n > max_bytes) throw Error(std::string(what) + " longer than " + std::to_string(max_bytes) + " bytes");
    std::string s(bytes_.data() + at_, n);
    at_ += n;
    return s;
  }

 private:
  const std::string& bytes_;
  size_t at_, end_;
};

std::string Checksum(const std::string& bytes, size_t begin) {
  unsigned char hash[kChecksumBytes];
  crypto_generichash(hash, sizeof(hash), reinterpret_cast<const unsigned char*>(bytes.data()) + begin,
                     bytes.size() - begin, nullptr, 0);
  return std::string(reinterpret_cast<const char*>(hash), sizeof(hash));
}

std::string Hex(const std::string& bytes) {
  static const char* digits = "0123456789abcdef";
  std::string out;
  for (unsigned char c : bytes) {
    out += digits[c >> 4];
    out += digits[c & 15];
  }
  return out;
}

void WritePose(Writer* w, const Rigid3d& pose) {
  const Eigen::Quaterniond& q = pose.rotation;
  for (double v : {q.w(), q.x(), q.y(), q.z(), pose.translation.x(), pose.translation.y(), pose.translation.z()}) {
    w->F64(v);
  }
}

Rigid3d ReadPose(Reader* r) {
  double v[7];
  for (double& x : v) x = r->F64("a keyframe's pose");
  const Eigen::Quaterniond q(v[0], v[1], v[2], v[3]);
  if (std::abs(q.norm() - 1.0) > 1e-6) throw Error("a keyframe's rotation is not a unit quaternion");
  return Rigid3d(q, Eigen::Vector3d(v[4], v[5], v[6]));
}

}  // namespace

SavedMap MakeSavedMap(const Map& map, const std::function<const Camera*(KeyframeId)>& camera_of,
                      const std::string& description, SubmapId id) {
  std::vector<KeyframeId> keyframes;
  for (const auto& [kf, keyframe] : map.keyframes()) {
    if (camera_of(kf)) keyframes.push_back(kf);
  }
  std::sort(keyframes.begin(), keyframes.end());
  const auto kept = [&](KeyframeId kf) { return std::binary_search(keyframes.begin(), keyframes.end(), kf); };
  std::vector<MapPointId> points;
  for (const auto& [p, point] : map.points()) {
    if (std::any_of(point.observations.begin(), point.observations.end(),
                    [&](const auto& observation) { return kept(observation.first); })) {
      points.push_back(p);
    }
  }
  std::sort(points.begin(), points.end());
  std::map<KeyframeId, KeyframeId> new_keyframe;
  std::map<MapPointId, MapPointId> new_point;
  for (size_t i = 0; i < keyframes.size(); ++i) new_keyframe[keyframes[i]] = MakeKeyframeId(id, i);
  for (size_t j = 0; j < points.size(); ++j) new_point[points[j]] = MakeMapPointId(id, j);
  const auto renumbered = [&](KeyframeId kf) {
    const auto it = new_keyframe.find(kf);
    return it == new_keyframe.end() ? KeyframeId() : it->second;
  };

  SavedMap saved(Map(id, map.pyramid(), static_cast<uint32_t>(points.size())));
  saved.description = description;
  for (MapPointId p : points) {
    MapPoint point = *map.FindPoint(p);
    point.id = new_point.at(p);
    point.observations.clear();
    point.reference_keyframe = renumbered(point.reference_keyframe);
    point.first_keyframe = renumbered(point.first_keyframe);
    saved.map.AddPoint(std::move(point));
  }
  for (KeyframeId kf : keyframes) {
    const Keyframe& original = *map.FindKeyframe(kf);
    Keyframe keyframe;
    keyframe.id = new_keyframe.at(kf);
    keyframe.frame_index = original.frame_index;
    keyframe.t_ns = original.t_ns;
    keyframe.cam_from_world = original.cam_from_world;
    keyframe.keypoints = original.keypoints;
    keyframe.descriptors = original.descriptors.clone();
    keyframe.points.assign(original.points.size(), MapPointId());
    for (size_t i = 0; i < original.points.size(); ++i) {
      const auto it = new_point.find(original.points[i]);
      if (it != new_point.end()) keyframe.points[i] = it->second;
    }
    const Camera& camera = *camera_of(kf);
    int index = -1;
    for (size_t c = 0; c < saved.cameras.size() && index < 0; ++c) {
      if (saved.cameras[c].Describe() == camera.Describe()) index = static_cast<int>(c);
    }
    if (index < 0) {
      index = static_cast<int>(saved.cameras.size());
      saved.cameras.push_back(camera);
    }
    saved.camera_index[keyframe.id] = index;
    saved.source_keyframe[keyframe.id] = kf.value;
    saved.map.AddKeyframe(std::move(keyframe));
  }
  saved.map.ConnectAll();
  return saved;
}

std::string EncodeMapFile(const SavedMap& saved) {
  const Map& map = saved.map;
  const SubmapId id = map.id();
  Writer w;
  w.Bytes(kMagic, sizeof(kMagic));
  w.U32(kMapFileVersion);
  w.U32(static_cast<uint32_t>(kHeaderBytes));
  w.U64(0);                                                           // payload bytes, filled below
  w.Bytes(std::string(kChecksumBytes, '\0').data(), kChecksumBytes);  // filled below
  w.String(saved.description.substr(0, kMaxDescriptionBytes));
  w.U32(static_cast<uint32_t>(map.pyramid().num_levels));
  w.F64(map.pyramid().scale_factor);
  w.U32(static_cast<uint32_t>(saved.cameras.size()));
  for (const Camera& camera : saved.cameras) {
    w.U8(static_cast<uint8_t>(camera.model()));
    w.I32(camera.width());
    w.I32(camera.height());
    const std::vector<double> params = camera.params();
    w.U32(static_cast<uint32_t>(params.size()));
    for (double p : params) w.F64(p);
  }
  const auto index_of = [&](auto any_id) { return any_id.valid() && SubmapOf(any_id) == id ? IndexOf(any_id) : kNone; };
  // Points and keyframes are numbered 0.. in their submap; each is written at its index.
  const uint32_t num_points = static_cast<uint32_t>(map.num_points());
  w.U32(num_points);
  for (uint32_t j = 0; j < num_points; ++j) {
    const MapPoint* point = map.FindPoint(MakeMapPointId(id, j));
    if (!point) throw Error("EncodeMapFile: the map's points are not numbered 0.." + std::to_string(num_points - 1));
    for (int k = 0; k < 3; ++k) w.F64(point->position[k]);
    w.Bytes(point->descriptor.data(), 32);
    for (int k = 0; k < 3; ++k) w.F64(point->normal[k]);
    w.F32(point->min_distance);
    w.F32(point->max_distance);
    w.U32(index_of(point->reference_keyframe));
    w.U32(index_of(point->first_keyframe));
    w.I32(point->visible);
    w.I32(point->found);
  }
  const uint32_t num_keyframes = static_cast<uint32_t>(map.num_keyframes());
  w.U32(num_keyframes);
  for (uint32_t i = 0; i < num_keyframes; ++i) {
    const KeyframeId kf = MakeKeyframeId(id, i);
    const Keyframe* keyframe = map.FindKeyframe(kf);
    if (!keyframe) throw Error("EncodeMapFile: the map's keyframes are not numbered 0.." + std::to_string(i));
    w.I64(saved.source_keyframe.count(kf) ? saved.source_keyframe.at(kf) : kf.value);
    w.I32(keyframe->frame_index);
    w.I64(keyframe->t_ns);
    WritePose(&w, keyframe->cam_from_world);
    w.U32(static_cast<uint32_t>(saved.camera_index.at(kf)));
    const size_t n = keyframe->keypoints.size();
    if (keyframe->descriptors.rows != static_cast<int>(n) || keyframe->points.size() != n ||
        (n > 0 && (keyframe->descriptors.cols != 32 || !keyframe->descriptors.isContinuous()))) {
      throw Error("EncodeMapFile: keyframe " + std::to_string(i) + " has inconsistent features");
    }
    w.U32(static_cast<uint32_t>(n));
    for (size_t f = 0; f < n; ++f) {
      const cv::KeyPoint& k = keyframe->keypoints[f];
      w.F32(k.pt.x);
      w.F32(k.pt.y);
      w.F32(k.size);
      w.F32(k.angle);
      w.F32(k.response);
      w.I32(k.octave);
      w.U32(index_of(keyframe->points[f]));
      w.Bytes(keyframe->descriptors.ptr(static_cast<int>(f)), 32);
    }
  }
  std::string& bytes = w.bytes();
  const uint64_t payload = bytes.size() - kHeaderBytes;
  for (int i = 0; i < 8; ++i) bytes[16 + i] = static_cast<char>(payload >> (8 * i));
  const std::string sum = Checksum(bytes, kHeaderBytes);
  std::copy(sum.begin(), sum.end(), bytes.begin() + 24);
  return std::move(bytes);
}

SavedMap DecodeMapFile(const std::string& bytes, SubmapId id) {
  if (bytes.size() < kHeaderBytes || std::memcmp(bytes.data(), kMagic, sizeof(kMagic)) != 0) {
    throw Error("not a stitch map (no STITCHMP header)");
  }
  Reader header(bytes, 8, kHeaderBytes);
  const uint32_t version = header.U32("the header");
  if (version != kMapFileVersion) {
    throw Error("a map of format version " + std::to_string(version) + "; this stitch reads version " +
                std::to_string(kMapFileVersion) + " only");
  }
  if (header.U32("the header") != kHeaderBytes) throw Error("a damaged header (its length is wrong)");
  const uint64_t payload = header.U64("the header");
  if (payload != bytes.size() - kHeaderBytes) {
    throw Error("cut short or padded: the header says " + std::to_string(payload) + " bytes follow, the file has " +
                std::to_string(bytes.size() - kHeaderBytes));
  }
  if (bytes.compare(24, kChecksumBytes, Checksum(bytes, kHeaderBytes)) != 0) {
    throw Error("damaged: its checksum does not match its contents");
  }

  Reader r(bytes, kHeaderBytes, bytes.size());
  const std::string description = r.String(kMaxDescriptionBytes, "the description");
  const uint32_t levels = r.U32("the pyramid");
  const double scale_factor = r.F64("the pyramid");
  if (levels < 1 || levels > 16 || scale_factor <= 1.0 || scale_factor > 4.0) {
    throw Error("a pyramid of " + std::to_string(levels) + " levels at scale " + std::to_string(scale_factor));
  }
  OrbOptions orb;
  orb.num_levels = static_cast<int>(levels);
  orb.scale_factor = scale_factor;
  SavedMap saved(Map(id, ScalePyramid::From(orb)));
  saved.description = description;
  const uint32_t num_cameras = r.Count(kCameraMinBytes, "the cameras");
  if (num_cameras == 0) throw Error("a map without a camera");
  for (uint32_t c = 0; c < num_cameras; ++c) {
    const uint8_t model = r.U8("a camera");
    const int32_t width = r.I32("a camera");
    const int32_t height = r.I32("a camera");
    const uint32_t num_params = r.Count(8, "a camera's parameters");
    if (model > static_cast<uint8_t>(CameraModel::kFisheye) || num_params > Camera::kMaxParams) {
      throw Error("camera " + std::to_string(c) + ": an unknown model");
    }
    std::vector<double> params(num_params);
    for (double& p : params) p = r.F64("a camera's parameters");
    try {
      saved.cameras.emplace_back(static_cast<CameraModel>(model), width, height, params);
    } catch (const Error& e) {
      throw Error("camera " + std::to_string(c) + ": " + e.what());
    }
  }

  const uint32_t num_points = r.Count(kPointBytes, "the points");
  std::vector<MapPoint> points(num_points);
  std::vector<std::pair<uint32_t, uint32_t>> point_keyframes(num_points);
  for (uint32_t j = 0; j < num_points; ++j) {
    MapPoint& point = points[j];
    point.id = MakeMapPointId(id, j);
    for (int k = 0; k < 3; ++k) point.position[k] = r.F64("a point");
    r.Bytes(point.descriptor.data(), 32, "a point");
    for (int k = 0; k < 3; ++k) point.normal[k] = r.F64("a point");
    point.min_distance = r.F32("a point");
    point.max_distance = r.F32("a point");
    point_keyframes[j] = {r.U32("a point"), r.U32("a point")};
    point.visible = r.I32("a point");
    point.found = r.I32("a point");
    if (point.min_distance < 0 || point.max_distance < point.min_distance || point.visible < 0 || point.found < 0) {
      throw Error("point " + std::to_string(j) + ": an inconsistent distance range or count");
    }
  }
  const uint32_t num_keyframes = r.Count(kKeyframeMinBytes, "the keyframes");
  const auto keyframe_id = [&](uint32_t index, const std::string& what) {
    if (index == kNone) return KeyframeId();
    if (index >= num_keyframes)
      throw Error(what + " names keyframe " + std::to_string(index) + " of " + std::to_string(num_keyframes));
    return MakeKeyframeId(id, index);
  };
  for (uint32_t j = 0; j < num_points; ++j) {
    const std::string what = "point " + std::to_string(j);
    points[j].reference_keyframe = keyframe_id(point_keyframes[j].first, what);
    points[j].first_keyframe = keyframe_id(point_keyframes[j].second, what);
    saved.map.AddPoint(std::move(points[j]));
  }
  for (uint32_t i = 0; i < num_keyframes; ++i) {
    const std::string what = "keyframe " + std::to_string(i);
    Keyframe keyframe;
    keyframe.id = MakeKeyframeId(id, i);
    const int64_t source = r.I64("a keyframe");
    keyframe.frame_index = r.I32("a keyframe");
    keyframe.t_ns = r.I64("a keyframe");
    keyframe.cam_from_world = ReadPose(&r);
    const uint32_t camera = r.U32("a keyframe");
    if (camera >= num_cameras) throw Error(what + " names camera " + std::to_string(camera));
    const uint32_t n = r.Count(kFeatureBytes, "a keyframe's features");
    keyframe.keypoints.resize(n);
    keyframe.points.assign(n, MapPointId());
    keyframe.descriptors.create(static_cast<int>(n), 32, CV_8U);
    const Camera& lens = saved.cameras[camera];
    for (uint32_t f = 0; f < n; ++f) {
      cv::KeyPoint& k = keyframe.keypoints[f];
      k.pt.x = r.F32("a feature");
      k.pt.y = r.F32("a feature");
      k.size = r.F32("a feature");
      k.angle = r.F32("a feature");
      k.response = r.F32("a feature");
      k.octave = r.I32("a feature");
      const uint32_t point = r.U32("a feature");
      r.Bytes(keyframe.descriptors.ptr(static_cast<int>(f)), 32, "a feature");
      if (k.octave < 0 || k.octave >= static_cast<int>(levels) || !lens.InImage({k.pt.x, k.pt.y}, -1.0) ||
          k.angle < -1 || k.angle >= 360) {  // -1: OpenCV's "no orientation"
        throw Error(what + ", feature " + std::to_string(f) + ": outside its image or its pyramid");
      }
      if (point != kNone) {
        if (point >= num_points)
          throw Error(what + " observes point " + std::to_string(point) + " of " + std::to_string(num_points));
        keyframe.points[f] = MakeMapPointId(id, point);
      }
    }
    saved.camera_index[keyframe.id] = static_cast<int>(camera);
    saved.source_keyframe[keyframe.id] = source;
    Keyframe& added = saved.map.AddKeyframe(std::move(keyframe));
    // A point observed twice by one keyframe would leave the map inconsistent.
    std::map<MapPointId, int> seen;
    for (MapPointId p : added.points) {
      if (p.valid() && ++seen[p] > 1) throw Error(what + " observes point " + std::to_string(IndexOf(p)) + " twice");
    }
  }
  if (r.left() != 0) throw Error(std::to_string(r.left()) + " bytes after the map");
  saved.map.ConnectAll();
  return saved;
}

void WriteMapFile(const std::string& path, const SavedMap& saved) {
  WriteFileAtomically(path, EncodeMapFile(saved));
}

SavedMap ReadMapFile(const std::string& path, SubmapId id) {
  std::string bytes;
  try {
    bytes = ReadFileBytes(path);
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
  try {
    return DecodeMapFile(bytes, id);
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
}

MapFileSummary SummarizeMapFile(const std::string& bytes, const SavedMap& saved) {
  MapFileSummary s;
  s.version = kMapFileVersion;
  s.bytes = bytes.size();
  s.checksum = Hex(bytes.substr(24, kChecksumBytes));
  s.description = saved.description;
  s.cameras = static_cast<int>(saved.cameras.size());
  s.keyframes = static_cast<int>(saved.map.num_keyframes());
  s.points = static_cast<int>(saved.map.num_points());
  for (const auto& [id, point] : saved.map.points()) s.observations += static_cast<int64_t>(point.observations.size());
  return s;
}

}  // namespace stitch
