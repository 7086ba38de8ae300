#pragma once
// The pictures behind a run's frames, read again from what the run played: the synthetic flight
// rendered again (its gusts too), a dataset's image files (in colour where they are), a video
// decoded in order (in colour). The merger, on the ground, has no images; the launcher and the
// tools that work on a run folder have its source.

#include <functional>
#include <vector>

#include <opencv2/core.hpp>

#include "stitch/source/source.h"

namespace stitch {

// `frames`: counted from the first frame the run played (spec.start_frame of the sequence). Calls
// `take(frame, image)` for each, in increasing frame order, with a BGR or grey image. Throws
// stitch::Error: a live source, a source that is gone, a frame it does not hold or cannot read.
void ReadRunImages(const SourceSpec& spec, std::vector<int> frames,
                   const std::function<void(int frame, const cv::Mat& image)>& take);

}  // namespace stitch
