#pragma once
// Included by every generated message header (lcmtypes/harden_generated.cmake): the fewest bytes
// one element of an array takes on the wire, so that a decode refuses a count its message cannot
// hold before it resizes the array. A count checked against one byte per element let a 4 MB
// message allocate 1.5 GB: its keyframes cost 376 bytes each in memory.

#include <algorithm>
#include <cstdint>
#include <string>
#include <type_traits>

namespace stitch_lcm {

template <class Element>
int64_t MinEncodedBytes() {
  if constexpr (std::is_same_v<Element, std::string>) {
    return 5;  // its length (int32) and the terminating NUL
  } else if constexpr (std::is_arithmetic_v<Element>) {
    return static_cast<int64_t>(sizeof(Element));
  } else {
    // A message type: as it encodes with every array empty and every string "".
    return std::max<int64_t>(1, Element()._getEncodedSizeNoHash());
  }
}

// Whether `count` elements of `Element` can be in the `bytes_left` bytes of a message.
template <class Element>
bool CountFits(int64_t count, int64_t bytes_left) {
  return count >= 0 && count <= bytes_left / MinEncodedBytes<Element>();
}

}  // namespace stitch_lcm
