#pragma once
// A recorded source read ahead of its player: a thread of its own takes the frames out of the
// source (decoding a video, reading and decoding image files, rendering the synthetic flight,
// reducing each to its working size) while the player waits for the next frame's time. A camera
// played at its rate then sends a frame late only when reading falls behind on average, not when
// one frame's reading meets a busy moment of the machine (docs/speed.md, "Reading ahead").

#include <memory>

#include "stitch/io/image_sequence.h"

namespace stitch {

// `inner` read at most `frames` frames ahead of Next(); `inner` itself for a live source (it is
// read at its own rate and keeps only the newest frame) or `frames` <= 0. The frames, their order
// and their times are `inner`'s; an error `inner` throws is thrown by the Next() that would have
// returned its frame. The sequence's description, size, camera, rate and ground truth are `inner`'s
// when it is wrapped.
std::unique_ptr<ImageSequence> ReadAhead(std::unique_ptr<ImageSequence> inner, int frames);

}  // namespace stitch
