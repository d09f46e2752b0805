#include "common/image.h"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <stdexcept>

namespace epr {
namespace {

float linear_to_srgb(float c) {
  c = std::clamp(c, 0.f, 1.f);
  return c <= 0.0031308f ? 12.92f * c : 1.055f * std::pow(c, 1 / 2.4f) - 0.055f;
}

std::vector<unsigned char> to_srgb8(const Image& img) {
  std::vector<unsigned char> out(img.data.size());
  for (size_t i = 0; i < img.data.size(); ++i) {
    float v = img.data[i];
    if (!std::isfinite(v)) v = 0;
    out[i] = static_cast<unsigned char>(std::lround(linear_to_srgb(v) * 255.f));
  }
  return out;
}

void write_with(OIIO::ImageOutput& out, const std::string& name, const OIIO::ImageSpec& spec, OIIO::TypeDesc type,
                const void* pixels) {
  if (!out.open(name, spec) || !out.write_image(type, pixels) || !out.close())
    throw std::runtime_error(fmt::format("cannot write image '{}': {}", name, out.geterror()));
}

}  // namespace

void write_exr(const std::string& path, const Image& img, const char* compression) {
  auto out = OIIO::ImageOutput::create(path);
  if (!out) throw std::runtime_error(fmt::format("cannot write '{}': {}", path, OIIO::geterror()));
  OIIO::ImageSpec spec(img.width, img.height, img.channels, OIIO::TypeDesc::FLOAT);
  spec.attribute("compression", compression);
  write_with(*out, path, spec, OIIO::TypeDesc::FLOAT, img.data.data());
}

void write_png_srgb(const std::string& path, const Image& img) {
  auto out = OIIO::ImageOutput::create(path);
  if (!out) throw std::runtime_error(fmt::format("cannot write '{}': {}", path, OIIO::geterror()));
  OIIO::ImageSpec spec(img.width, img.height, img.channels, OIIO::TypeDesc::UINT8);
  const auto bytes = to_srgb8(img);
  write_with(*out, path, spec, OIIO::TypeDesc::UINT8, bytes.data());
}

std::vector<unsigned char> encode_png_srgb(const Image& img) {
  std::vector<unsigned char> file;
  OIIO::Filesystem::IOVecOutput io(file);
  auto out = OIIO::ImageOutput::create("png");
  if (!out) throw std::runtime_error("PNG encoder unavailable");
  OIIO::ImageSpec spec(img.width, img.height, img.channels, OIIO::TypeDesc::UINT8);
  out->set_ioproxy(&io);
  const auto bytes = to_srgb8(img);
  write_with(*out, "preview.png", spec, OIIO::TypeDesc::UINT8, bytes.data());
  return file;
}

Image read_image(const std::string& path) {
  // Colour as stored, not multiplied by alpha (OpenImageIO associates alpha by default).
  OIIO::ImageSpec config;
  config.attribute("oiio:UnassociatedAlpha", 1);
  auto in = OIIO::ImageInput::open(path, &config);
  if (!in) throw std::runtime_error(fmt::format("cannot read image '{}': {}", path, OIIO::geterror()));
  const OIIO::ImageSpec& spec = in->spec();
  if (spec.width <= 0 || spec.height <= 0 || spec.nchannels <= 0 || spec.width > 65536 || spec.height > 65536)
    throw std::runtime_error(fmt::format("image '{}' has an unusable size", path));
  Image img(spec.width, spec.height, spec.nchannels);
  if (!in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, img.data.data()))
    throw std::runtime_error(fmt::format("cannot read image '{}': {}", path, in->geterror()));
  // 8-bit files hold sRGB-encoded colour: linearise so textures are in the renderer's space.
  if (spec.format == OIIO::TypeDesc::UINT8 || spec.format == OIIO::TypeDesc::UINT16) {
    for (float& v : img.data) v = v <= 0.04045f ? v / 12.92f : std::pow((v + 0.055f) / 1.055f, 2.4f);
  }
  return img;
}

Image heat_map(const Image& scalar, float max_value) {
  Image out(scalar.width, scalar.height, 3);
  const Vec3 stops[] = {{0, 0, 0}, {0, 0, 1}, {0, 1, 0}, {1, 1, 0}, {1, 1, 1}};
  for (int y = 0; y < scalar.height; ++y)
    for (int x = 0; x < scalar.width; ++x) {
      float t = max_value > 0 ? std::clamp(scalar.at(x, y)[0] / max_value, 0.f, 1.f) : 0.f;
      const float f = t * 4;
      const int i = std::min(3, int(f));
      const float w = f - float(i);
      out.set_rgb(x, y, stops[i] * (1 - w) + stops[i + 1] * w);
    }
  return out;
}

}  // namespace epr
