#pragma once
// Settings of the mapper service (the `mapper:` section of a stitch config).

#include <string>

#include "stitch/delivery/submap_sender.h"
#include "stitch/mapping/mapping_options.h"

namespace stitch {

struct MapperOptions {
  int max_queued_keyframes = 200;  // beyond this the oldest waiting keyframe is dropped (and logged)
  // The submap delivery to the merger: thinning for the link, holding back behind a backlog,
  // answers to the merger's requests, the linger at stop (SenderOptions; its keys sit in this
  // section).
  SenderOptions delivery;
  MappingOptions mapping;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("max_queued_keyframes", max_queued_keyframes, "keyframes that may wait for the mapper");
    delivery.VisitFields(v);
    v("mapping", mapping, "the local mapping algorithm");
  }
  bool Check(std::string* why) const {
    if (max_queued_keyframes < 1) {
      if (why) *why = "mapper.max_queued_keyframes must be >= 1";
      return false;
    }
    if (!delivery.Check("mapper", why)) return false;
    return mapping.Check(why);
  }
};

}  // namespace stitch
