#pragma once
// Settings of the tracker service (the `tracker:` section of a stitch config).

#include <string>

namespace stitch {

struct TrackerOptions {
  int max_queued_frames = 2;       // realtime: frames waiting beyond this are dropped, oldest first
  std::string on_loss = "submap";  // submap: close the map and start a new one; relocalize: ORB-SLAM2-like

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("max_queued_frames", max_queued_frames, "frames that may wait for the tracker; older ones are dropped");
    v("on_loss", on_loss, "after tracking loss: submap (stitch) or relocalize (ORB-SLAM2-like baseline)");
  }

  bool Check(std::string* why) const {
    if (max_queued_frames < 1 || max_queued_frames > 1000) {
      if (why) *why = "tracker.max_queued_frames must be in [1, 1000]";
      return false;
    }
    if (on_loss != "submap" && on_loss != "relocalize") {
      if (why) *why = "tracker.on_loss must be submap or relocalize";
      return false;
    }
    return true;
  }
};

}  // namespace stitch
