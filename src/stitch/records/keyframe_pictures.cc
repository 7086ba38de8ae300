#include "stitch/records/keyframe_pictures.h"

#include <cstdio>
#include <filesystem>
#include <sstream>

#include "stitch/util/error.h"
#include "stitch/util/text_file.h"

namespace fs = std::filesystem;

namespace stitch {

std::string KeyframePictureName(int agent, int frame_index) {
  char name[64];
  std::snprintf(name, sizeof(name), "agent%d-frame%06d.jpg", agent, frame_index);
  return name;
}

KeyframePictureStore::KeyframePictureStore(std::string record_dir) : dir_(std::move(record_dir)) {}

bool KeyframePictureStore::Add(const KeyframePicture& picture, std::string* why) {
  if (dir_.empty()) return true;
  try {
    const fs::path folder = fs::path(dir_) / "keyframe_images";
    if (!index_.is_open()) {
      fs::create_directories(folder);
      const fs::path index = fs::path(dir_) / "keyframe_images.tsv";
      const bool fresh = !fs::exists(index);
      index_.open(index, std::ios::app);
      if (!index_) throw Error(index.string() + ": cannot be written");
      if (fresh) {
        index_ << "# agent frame_index t_ns submap_id keyframe_id camera_width camera_height width height bytes "
                  "(keyframe_images/agentA-frameNNNNNN.jpg)\n";
      }
    }
    WriteFileAtomically((folder / KeyframePictureName(picture.agent, picture.frame_index)).string(),
                        std::string(picture.jpeg.begin(), picture.jpeg.end()));
    index_ << picture.agent << ' ' << picture.frame_index << ' ' << picture.t_ns << ' ' << picture.submap_id << ' '
           << picture.keyframe_id << ' ' << picture.camera_width << ' ' << picture.camera_height << ' ' << picture.width
           << ' ' << picture.height << ' ' << picture.jpeg.size() << '\n';
    index_.flush();
    if (!index_) throw Error("keyframe_images.tsv: cannot be written");
  } catch (const std::exception& e) {
    *why = e.what();
    return false;
  }
  ++pictures_;
  bytes_ += static_cast<int64_t>(picture.jpeg.size());
  return true;
}

std::vector<KeyframePicture> ReadKeyframePictureIndex(const std::string& record_dir) {
  std::vector<KeyframePicture> pictures;
  const fs::path path = fs::path(record_dir) / "keyframe_images.tsv";
  std::ifstream in(path);
  if (!in) return pictures;
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    if (line.empty() || line[0] == '#') continue;
    std::istringstream fields(line);
    KeyframePicture p;
    size_t bytes = 0;
    if (!(fields >> p.agent >> p.frame_index >> p.t_ns >> p.submap_id >> p.keyframe_id >> p.camera_width >>
          p.camera_height >> p.width >> p.height >> bytes)) {
      throw Error(path.string() + ":" + std::to_string(number) + ": not a keyframe picture's line");
    }
    pictures.push_back(p);
  }
  return pictures;
}

}  // namespace stitch
