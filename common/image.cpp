#include "common/image.h"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <stdexcept>

#include "common/checked_file.h"

namespace epr {

float linear_to_srgb(float c) {
  c = std::clamp(c, 0.f, 1.f);
  return c <= 0.0031308f ? 12.92f * c : 1.055f * std::pow(c, 1 / 2.4f) - 0.055f;
}

namespace {

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

// OpenImageIO's writers over a CheckedFile: a write that fails (a full disk, a file size limit) is
// reported with its errno, where OpenImageIO's own file output would leave a short file and succeed.
class CheckedFileProxy final : public OIIO::Filesystem::IOProxy {
 public:
  explicit CheckedFileProxy(const std::string& path) : IOProxy(path, Write), file_(path) {}
  const char* proxytype() const override { return "epr-checked-file"; }
  size_t write(const void* buf, size_t size) override {
    const size_t n = file_.pwrite(buf, size, uint64_t(m_pos));
    m_pos += int64_t(n);
    return n;
  }
  size_t pwrite(const void* buf, size_t size, int64_t offset) override {
    return file_.pwrite(buf, size, uint64_t(offset));
  }
  size_t read(void*, size_t) override { return 0; }
  size_t pread(void*, size_t, int64_t) override { return 0; }
  size_t size() const override { return size_t(file_.size()); }
  CheckedFile& file() { return file_; }

 private:
  CheckedFile file_;
};

// Writes through a CheckedFileProxy, fsyncs and closes; the error names the errno if a write failed.
void write_checked(const std::string& path, const OIIO::ImageSpec& spec, OIIO::TypeDesc type, const void* pixels) {
  auto out = OIIO::ImageOutput::create(path);
  if (!out) throw std::runtime_error(fmt::format("cannot write '{}': {}", path, OIIO::geterror()));
  CheckedFileProxy proxy(path);
  out->set_ioproxy(&proxy);
  try {
    write_with(*out, path, spec, type, pixels);
  } catch (const std::exception&) {
    if (proxy.file().error() == 0) throw;
  }
  out.reset();
  proxy.file().finish();  // throws naming the errno of a failed write
}
}  // namespace

void write_exr(const std::string& path, const Image& img, const char* compression) {
  OIIO::ImageSpec spec(img.width, img.height, img.channels, OIIO::TypeDesc::FLOAT);
  spec.attribute("compression", compression);
  write_checked(path, spec, OIIO::TypeDesc::FLOAT, img.data.data());
}

void write_png_srgb(const std::string& path, const Image& img) {
  OIIO::ImageSpec spec(img.width, img.height, img.channels, OIIO::TypeDesc::UINT8);
  const auto bytes = to_srgb8(img);
  write_checked(path, spec, OIIO::TypeDesc::UINT8, bytes.data());
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

Image read_image(const std::string& path, bool colour) {
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
  if (colour && (spec.format == OIIO::TypeDesc::UINT8 || spec.format == OIIO::TypeDesc::UINT16)) {
    // Such a file has at most 2^bits values, v = code / (2^bits - 1): each one is linearised once, the
    // result kept by its code with the v it came from (a v that is not the code's own is computed).
    auto linear = [](float v) { return v <= 0.04045f ? v / 12.92f : std::pow((v + 0.055f) / 1.055f, 2.4f); };
    const float top = spec.format == OIIO::TypeDesc::UINT8 ? 255.f : 65535.f;
    std::vector<float> from(size_t(top) + 1, -1.f), to(size_t(top) + 1);
    for (float& v : img.data) {
      if (!(v >= 0.f && v <= 1.f)) {
        v = linear(v);
        continue;
      }
      const size_t code = size_t(v * top + 0.5f);
      if (from[code] != v) {
        from[code] = v;
        to[code] = linear(v);
      }
      v = to[code];
    }
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
