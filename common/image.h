// Float images and their files. Every read and write goes through OpenImageIO.
#pragma once

#include <string>
#include <vector>

#include "common/math.h"

namespace epr {

/// Interleaved float image, row 0 at the top. Colour data is linear RGB.
struct Image {
  int width = 0, height = 0, channels = 3;
  std::vector<float> data;

  Image() = default;
  Image(int w, int h, int c = 3) : width(w), height(h), channels(c), data(size_t(w) * size_t(h) * size_t(c), 0.f) {}
  float* at(int x, int y) { return &data[(size_t(y) * size_t(width) + size_t(x)) * size_t(channels)]; }
  const float* at(int x, int y) const { return &data[(size_t(y) * size_t(width) + size_t(x)) * size_t(channels)]; }
  Vec3 rgb(int x, int y) const {
    const float* p = at(x, y);
    return channels >= 3 ? Vec3(p[0], p[1], p[2]) : Vec3(p[0]);
  }
  void set_rgb(int x, int y, Vec3 c) {
    float* p = at(x, y);
    p[0] = c.x;
    if (channels >= 3) {
      p[1] = c.y;
      p[2] = c.z;
    }
  }
};

/// Linear 32-bit float OpenEXR, `compression` as OpenImageIO names it ("zip", "none", ...), fsynced.
/// Throws std::runtime_error naming the file on failure (std::system_error naming the errno when a
/// write fails: a full disk leaves a short file, never a reported success).
void write_exr(const std::string& path, const Image& img, const char* compression = "zip");
/// The sRGB transfer curve of a linear value, clamped to [0, 1].
float linear_to_srgb(float c);
/// 8-bit PNG; colour is clamped to [0,1] and encoded with the sRGB transfer curve. Written and
/// reported like write_exr().
void write_png_srgb(const std::string& path, const Image& img);
/// The same PNG encoded to bytes in memory (for previews served over the network).
std::vector<unsigned char> encode_png_srgb(const Image& img);
/// Any format OpenImageIO reads, as float; 8- and 16-bit inputs hold sRGB-encoded colour and are
/// linearised unless `colour` is false (data such as normal maps, read as stored).
Image read_image(const std::string& path, bool colour = true);

/// False-colour heat map (black - blue - green - yellow - white) of a one-channel image, 0 .. max_value.
Image heat_map(const Image& scalar, float max_value);

}  // namespace epr
