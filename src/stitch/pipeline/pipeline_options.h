#pragma once
// Settings of the algorithms run inline (RunInline): the tracking, mapping and merging sections
// of a stitch config. A light header.

#include <string>

#include "stitch/mapping/mapping_options.h"
#include "stitch/merging/merger_options.h"
#include "stitch/tracking/tracking_options.h"

namespace stitch {

// The algorithms' settings (the matching sections of a stitch config).
struct PipelineOptions {
  TrackingOptions tracking;
  std::string on_loss = "submap";  // submap or relocalize (ParseLossPolicy)
  MappingOptions mapping;
  MergerOptions merger;
};

}  // namespace stitch
