#pragma once
// Settings of the mapper service (the `mapper:` section of a stitch config).

#include <string>

#include "services/mapper/local_mapping.h"

namespace stitch {

struct MapperOptions {
  int max_queued_keyframes = 200;  // beyond this the oldest waiting keyframe is dropped (and logged)
  MappingOptions mapping;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("max_queued_keyframes", max_queued_keyframes, "keyframes that may wait for the mapper");
    v("mapping", mapping, "the local mapping algorithm");
  }
  bool Check(std::string* why) const {
    if (max_queued_keyframes < 1) {
      if (why) *why = "mapper.max_queued_keyframes must be >= 1";
      return false;
    }
    return mapping.Check(why);
  }
};

}  // namespace stitch
