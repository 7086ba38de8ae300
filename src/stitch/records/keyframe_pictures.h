#pragma once
// The keyframes' pictures the ground received (tracker.keyframe_images), kept with the merger's
// records: RECORD_DIR/keyframe_images/agentA-frameNNNNNN.jpg (COLMAP's names for the keyframes'
// images) and an index, RECORD_DIR/keyframe_images.tsv, a line per picture:
//   agent frame_index t_ns submap_id keyframe_id camera_width camera_height width height bytes
// What `stitch mosaic` lays on the map where the flight's own images are not at hand (a live
// camera, a ground station without the recording).

#include <cstdint>
#include <fstream>
#include <string>
#include <vector>

namespace stitch {

struct KeyframePicture {
  int agent = 0;
  int frame_index = 0;
  int64_t t_ns = 0;
  int64_t sent_utime = 0;  // when the aircraft sent it (its message's header, the sender's wall clock)
  int64_t submap_id = 0;
  int64_t keyframe_id = 0;
  int camera_width = 0, camera_height = 0;  // the keyframe's camera's image size
  int width = 0, height = 0;                // the picture's
  std::vector<uint8_t> jpeg;
};

// The picture's file name under keyframe_images/.
std::string KeyframePictureName(int agent, int frame_index);

class KeyframePictureStore {
 public:
  // Nothing is written when `record_dir` is empty.
  explicit KeyframePictureStore(std::string record_dir);
  // Writes the picture (atomically) and its index line; a second picture of the same frame
  // replaces the first. False, with `why`, when it cannot be written.
  bool Add(const KeyframePicture& picture, std::string* why);
  int64_t pictures() const { return pictures_; }
  int64_t bytes() const { return bytes_; }

 private:
  std::string dir_;
  std::ofstream index_;
  int64_t pictures_ = 0, bytes_ = 0;
};

// The index of RECORD_DIR's pictures (without their bytes), in the order received; empty when
// there is none. Throws stitch::Error naming the line of an index that is not one.
std::vector<KeyframePicture> ReadKeyframePictureIndex(const std::string& record_dir);

}  // namespace stitch
