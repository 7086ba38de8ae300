#pragma once
// 256-bit binary descriptors (ORB) and their Hamming distance.

#include <array>
#include <cstdint>
#include <cstring>

#include <opencv2/core.hpp>

namespace stitch {

constexpr int kDescriptorBytes = 32;
using Descriptor = std::array<uint8_t, kDescriptorBytes>;

inline int HammingDistance(const uint8_t* a, const uint8_t* b) {
  uint64_t x[4], y[4];
  std::memcpy(x, a, 32);
  std::memcpy(y, b, 32);
  return __builtin_popcountll(x[0] ^ y[0]) + __builtin_popcountll(x[1] ^ y[1]) + __builtin_popcountll(x[2] ^ y[2]) +
         __builtin_popcountll(x[3] ^ y[3]);
}
inline int HammingDistance(const Descriptor& a, const Descriptor& b) {
  return HammingDistance(a.data(), b.data());
}

// A descriptor from its 32 bytes (e.g. row i of an N x 32 CV_8U matrix: descriptors.ptr<uint8_t>(i)).
inline Descriptor ToDescriptor(const uint8_t* bytes) {
  Descriptor d;
  std::memcpy(d.data(), bytes, kDescriptorBytes);
  return d;
}

// Matching thresholds in bits (of 256), as used by ORB-SLAM.
constexpr int kDescriptorDistanceHigh = 100;
constexpr int kDescriptorDistanceLow = 50;

}  // namespace stitch
