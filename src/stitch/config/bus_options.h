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

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("key_file", key_file,
      "key every service of this side's bus shares (from `stitch-link keygen FILE`): messages without its tag, "
      "or heard before, are refused (empty: none)");
  }
  bool Check(std::string*) const { return true; }
};

}  // namespace stitch
