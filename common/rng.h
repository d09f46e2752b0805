// Counter-based random numbers keyed by (seed, pixel, sample index, dimension).
//
// There is no generator state to carry between paths: every number is a pure function of its key,
// so any tile can be traced again, in any order, on any thread or machine, and give bit-identical
// results. This is what the distributed correctness tests rely on. The hash is a chain of
// SplitMix64 finalisers, which passes BigCrush when used as a counter-based generator.
#pragma once

#include <cstdint>

#include "common/math.h"

namespace epr {

constexpr uint64_t mix64(uint64_t z) {
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

/// The part of the hash that does not depend on the dimension.
constexpr uint64_t hash_path_key(uint64_t seed, uint32_t pixel, uint32_t sample) {
  return mix64(mix64(seed + 0x9e3779b97f4a7c15ULL) ^ ((uint64_t(pixel) << 32) | sample));
}
constexpr uint64_t hash_dimension(uint64_t path_key, uint32_t dimension) {
  return mix64(path_key + (uint64_t(dimension) + 1) * 0x9e3779b97f4a7c15ULL);
}

/// 64 random bits for one key.
constexpr uint64_t hash_key(uint64_t seed, uint32_t pixel, uint32_t sample, uint32_t dimension) {
  return hash_dimension(hash_path_key(seed, pixel, sample), dimension);
}

/// A float uniformly distributed in [0, 1) from the top 24 bits.
constexpr float bits_to_unit_float(uint64_t bits) { return float(bits >> 40) * 0x1p-24f; }

/// The random numbers of one path: pixel p's sample number s. Dimensions are consumed in order;
/// next() equals bits_to_unit_float(hash_key(seed, pixel, sample, dimension)), with the
/// dimension-independent part of the hash computed once per path. next2() takes a pair from one
/// dimension's 64 bits: bits 40-63 and bits 16-39, 24 bits each.
class SampleStream {
 public:
  constexpr SampleStream(uint64_t seed, uint32_t pixel, uint32_t sample) : key_(hash_path_key(seed, pixel, sample)) {}

  float next() { return bits_to_unit_float(hash_dimension(key_, dimension_++)); }
  Vec2 next2() {
    const uint64_t bits = hash_dimension(key_, dimension_++);
    return {bits_to_unit_float(bits), bits_to_unit_float(bits << 24)};
  }
  uint32_t dimension() const { return dimension_; }

 private:
  uint64_t key_;
  uint32_t dimension_ = 0;
};

}  // namespace epr
