// SPDX-License-Identifier: MIT
// random.h — a small deterministic random generator (splitmix64), identical on every platform,
// so scenes and rays depend only on their seed.
#pragma once
#include <cstdint>

namespace mbvh {

class Rng {
public:
  explicit Rng(std::uint64_t seed) : s_(seed * 0x9E3779B97F4A7C15ull + 0x632BE59BD9B4E019ull) {}
  std::uint64_t next() {
    std::uint64_t z = (s_ += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  /// Uniform in [0, 1) with 24 random bits.
  float uniform() { return static_cast<float>(next() >> 40) * 0x1p-24f; }
  /// Uniform in [0, 1) with 53 random bits.
  double uniform_d() { return static_cast<double>(next() >> 11) * 0x1p-53; }

private:
  std::uint64_t s_;
};

}  // namespace mbvh
