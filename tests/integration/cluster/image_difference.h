// Image comparisons of the process tests: an empty string when two images agree, otherwise how many
// values differ and where the first one is (for the assertion's message).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstring>
#include <sstream>
#include <string>

#include "common/image.h"

namespace epr::testing {

inline std::string first_difference_at(const Image& a, const Image& b, size_t n, size_t first) {
  const size_t px = first / size_t(a.channels);
  std::ostringstream ss;
  ss << n << " of " << a.data.size() << " values differ; first at pixel (" << px % size_t(a.width) << ", "
     << px / size_t(a.width) << ") channel " << first % size_t(a.channels) << ": " << a.data[first] << " vs "
     << b.data[first];
  return ss.str();
}

inline std::string shape_difference(const Image& a, const Image& b) {
  if (a.width == b.width && a.height == b.height && a.channels == b.channels && a.data.size() == b.data.size())
    return "";
  return "shapes differ: " + std::to_string(a.width) + "x" + std::to_string(a.height) + "x" +
         std::to_string(a.channels) + " vs " + std::to_string(b.width) + "x" + std::to_string(b.height) + "x" +
         std::to_string(b.channels);
}

/// "" when a and b are bit-identical.
inline std::string exact_difference(const Image& a, const Image& b) {
  if (auto shape = shape_difference(a, b); !shape.empty()) return shape;
  size_t n = 0, first = 0;
  for (size_t i = 0; i < a.data.size(); ++i)
    if (std::memcmp(&a.data[i], &b.data[i], sizeof(float)) != 0 && n++ == 0) first = i;
  return n ? first_difference_at(a, b, n, first) : "";
}

/// "" when every value is finite and agrees within `abs` + `rel` x the larger magnitude (float
/// rounding of sums added in another order, by default).
inline std::string close_difference(const Image& a, const Image& b, float rel = 1e-4f, float abs = 1e-5f) {
  if (auto shape = shape_difference(a, b); !shape.empty()) return shape;
  size_t n = 0, first = 0;
  for (size_t i = 0; i < a.data.size(); ++i) {
    const float x = a.data[i], y = b.data[i];
    const bool ok =
        std::isfinite(x) && std::isfinite(y) && std::fabs(x - y) <= abs + rel * std::max(std::fabs(x), std::fabs(y));
    if (!ok && n++ == 0) first = i;
  }
  return n ? first_difference_at(a, b, n, first) + " beyond float rounding" : "";
}

}  // namespace epr::testing
