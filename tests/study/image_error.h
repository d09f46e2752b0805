// Image measures the study tests share: the trimmed relative MSE of an image against a reference
// (per pixel the channels' mean of (x - r)^2 / (r^2 + 0.01), the largest 1 % of pixel terms left
// out), and the mean of an image, each over a mask of pixels or the whole image.
#pragma once

#include <algorithm>
#include <cstdint>
#include <vector>

#include "common/image.h"

namespace epr {

using Mask = std::vector<uint8_t>;  // per pixel, row-major; non-zero: in the region

/// Trimmed rMSE of `x` against `ref` over `mask` (all pixels if empty).
inline double rmse(const Image& x, const Image& ref, const Mask& mask = {}) {
  std::vector<double> e;
  for (int y = 0; y < ref.height; ++y)
    for (int xp = 0; xp < ref.width; ++xp) {
      if (!mask.empty() && !mask[size_t(y) * size_t(ref.width) + size_t(xp)]) continue;
      double s = 0;
      for (int c = 0; c < 3; ++c) {
        const double r = ref.at(xp, y)[c], d = double(x.at(xp, y)[c]) - r;
        s += d * d / (r * r + 0.01) / 3;
      }
      e.push_back(s);
    }
  const size_t keep = e.size() - e.size() / 100;
  std::nth_element(e.begin(), e.begin() + ptrdiff_t(keep), e.end());
  double sum = 0;
  for (size_t i = 0; i < keep; ++i) sum += e[i];
  return sum / double(std::max<size_t>(1, keep));
}

/// Mean of the channels' mean over `mask` (all pixels if empty).
inline double mean(const Image& img, const Mask& mask = {}) {
  double s = 0;
  size_t n = 0;
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      if (!mask.empty() && !mask[size_t(y) * size_t(img.width) + size_t(x)]) continue;
      const float* p = img.at(x, y);
      s += (double(p[0]) + p[1] + p[2]) / 3;
      ++n;
    }
  return s / double(std::max<size_t>(1, n));
}

}  // namespace epr
