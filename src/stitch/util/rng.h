#pragma once
// Deterministic random numbers, identical on every platform and standard library (std::
// distributions are not), so a seed reproduces the same synthetic flight everywhere.

#include <cmath>
#include <cstdint>

namespace stitch {

// SplitMix64: tiny, fast, good enough for scene generation and noise.
class Rng {
 public:
  explicit Rng(uint64_t seed) : state_(seed) {}

  uint64_t NextU64() {
    uint64_t z = (state_ += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
  }
  // Uniform in [0, 1).
  double Uniform() { return static_cast<double>(NextU64() >> 11) * 0x1.0p-53; }
  double Uniform(double lo, double hi) { return lo + (hi - lo) * Uniform(); }
  // Uniform integer in [lo, hi].
  int UniformInt(int lo, int hi) { return lo + static_cast<int>(NextU64() % static_cast<uint64_t>(hi - lo + 1)); }
  // Standard normal (Box-Muller, one value per call).
  double Normal() {
    const double u1 = 1.0 - Uniform();  // (0, 1]
    const double u2 = Uniform();
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2);
  }
  double Normal(double mean, double sigma) { return mean + sigma * Normal(); }

 private:
  uint64_t state_;
};

// Stateless hash of integers to 64 bits (for noise that must not depend on evaluation order).
inline uint64_t HashU64(uint64_t a, uint64_t b = 0, uint64_t c = 0) {
  Rng rng(a * 0x9E3779B97F4A7C15ULL ^ (b + 0x632BE59BD9B4E019ULL) * 0xC2B2AE3D27D4EB4FULL ^
          (c + 0x165667B19E3779F9ULL));
  rng.NextU64();
  return rng.NextU64();
}

}  // namespace stitch
