#pragma once
// LCM's wire and log formats store integers big-endian.

#include <cstdint>

namespace stitch {

// The `count` (4 or 8) bytes at `bytes` as a big-endian integer; 4 bytes are sign-extended (int32).
inline int64_t BigEndian(const uint8_t* bytes, int count) {
  uint64_t value = 0;
  for (int i = 0; i < count; ++i) value = (value << 8) | bytes[i];
  return count == 4 ? static_cast<int32_t>(static_cast<uint32_t>(value)) : static_cast<int64_t>(value);
}

}  // namespace stitch
