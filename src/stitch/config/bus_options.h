#pragma once
// Settings of one side's bus (the `bus:` section of a stitch config): every service of a side
// must be given the same ones.

#include <string>

namespace stitch {

struct BusOptions {
  // Where the side's bus spans several computers (an aircraft with a companion computer beside
  // the flight computer, a ground station's LAN): a key file of 64 hex digits, mode 0600
  // (`stitch-link keygen FILE` makes one), given to every service of the side. Each message is
  // then tagged with it and a message without its tag, or one heard before, is refused
  // (services/common/bus_auth.h). Empty: no tags (one computer, `ttl=0`; LCM's own tools read
  // the bus).
  std::string key_file;
  // The camera's frames (ingest -> tracker) on an LCM URL of their own, e.g. the bus's multicast
  // group on another port. On one bus every service's socket receives every frame (LCM's udpm
  // sends each datagram to all of them, and a service drops what it did not subscribe to only
  // after the kernel copied it): at 1080p and 30 fps that is 62 MB/s into each of them. Empty:
  // the bus itself. Only the ingest and the tracker open it.
  std::string frame_url;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("key_file", key_file,
      "key every service of this side's bus shares (from `stitch-link keygen FILE`): messages without its tag, "
      "or heard before, are refused (empty: none)");
    v("frame_url", frame_url,
      "LCM URL of the camera's frames (ingest -> tracker) when not the bus itself, e.g. its group on another port, so "
      "that no other service receives them (empty: the bus)");
  }
  bool Check(std::string* why) const {
    if (!frame_url.empty() && frame_url.find("://") == std::string::npos) {
      *why = "bus.frame_url must be an LCM URL (udpm://..., memq://), not '" + frame_url + "'";
      return false;
    }
    return true;
  }
};

}  // namespace stitch
