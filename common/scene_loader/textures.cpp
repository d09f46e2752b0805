// Textures named by map_Kd (colour) and map_d or a glTF MASK material (alpha masks): read through
// OpenImageIO inside the scene folder, one Texture per file, checked against the size limits before
// they are decoded. Colour is clamped to [0, 1] (it is an albedo); a mask is read as stored (alpha
// is not sRGB-encoded), and only files used as masks keep one.
#include <OpenImageIO/imageio.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <system_error>

#include "common/image.h"
#include "common/scene_loader/obj_context.h"
#include "common/scene_loader/text.h"

namespace epr::loader {
namespace {

namespace fs = std::filesystem;

void fill_rgb(Texture& t, const Image& img, const std::string& name, const std::string& file, size_t line,
              size_t* clamped) {
  t.rgb.resize(size_t(img.width) * size_t(img.height) * 3);
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      const Vec3 c = img.rgb(x, y);
      if (!is_finite(c)) fail(file, line, fmt::format("texture '{}' has non-finite texels", name));
      float* out = &t.rgb[(size_t(y) * size_t(img.width) + size_t(x)) * 3];
      for (int k = 0; k < 3; ++k) {
        const float v = std::clamp(c[k], 0.f, 1.f);
        if (v != c[k]) ++*clamped;
        out[k] = v;
      }
    }
}

/// The mask of the image at `path`: its alpha channel, or without one its first channel (kMask) or
/// 1 everywhere (kAlpha); values as stored, clamped to [0, 1].
std::vector<float> read_mask(const std::string& path, TextureUse use, const std::string& name, const std::string& file,
                             size_t line) {
  OIIO::ImageSpec config;
  config.attribute("oiio:UnassociatedAlpha", 1);
  auto in = OIIO::ImageInput::open(path, &config);
  if (!in) fail(file, line, fmt::format("cannot read texture '{}': {}", name, OIIO::geterror()));
  const OIIO::ImageSpec spec = in->spec();
  const int n = spec.nchannels;
  int channel = spec.alpha_channel;
  if (channel < 0 && (n == 2 || n == 4)) channel = n - 1;  // grey + alpha, RGBA without the tag
  std::vector<float> data(size_t(spec.width) * size_t(spec.height) * size_t(n));
  if (!in->read_image(0, 0, 0, n, OIIO::TypeDesc::FLOAT, data.data()))
    fail(file, line, fmt::format("cannot read texture '{}': {}", name, in->geterror()));
  std::vector<float> alpha(size_t(spec.width) * size_t(spec.height), 1.f);
  if (channel < 0 && use == TextureUse::kAlpha) return alpha;
  if (channel < 0) channel = 0;
  for (size_t p = 0; p < alpha.size(); ++p) {
    const float a = data[p * size_t(n) + size_t(channel)];
    if (!std::isfinite(a)) fail(file, line, fmt::format("texture '{}' has non-finite texels", name));
    alpha[p] = std::clamp(a, 0.f, 1.f);
  }
  return alpha;
}

}  // namespace

int load_texture(ObjContext& ctx, const std::string& name, const fs::path& dir, const std::string& display_dir,
                 const std::string& file, size_t line, TextureUse use) {
  std::string portable = name;
  std::replace(portable.begin(), portable.end(), '\\', '/');  // textures named on Windows
  const FileRef ref = resolve_inside(ctx.root, dir, display_dir, portable, file, line, "texture");
  const bool data = use == TextureUse::kData;
  if (auto it = ctx.texture_of_path.find(ref.real); !data && it != ctx.texture_of_path.end()) {
    // Read before, perhaps for the other use: add what this use needs.
    Texture& t = ctx.textures[size_t(it->second)];
    if (use != TextureUse::kColour && t.alpha.empty()) {
      t.alpha = read_mask(ref.real.string(), use, name, file, line);
      if (t.alpha.size() != size_t(t.width) * size_t(t.height))
        fail(file, line, fmt::format("texture '{}' changed while the scene was read", name));
    } else if (use == TextureUse::kColour && t.rgb.empty()) {
      size_t clamped = 0;
      Image img;
      try {
        img = read_image(ref.real.string());
      } catch (const std::exception& e) {
        fail(file, line, fmt::format("cannot read texture '{}': {}", name, e.what()));
      }
      if (img.width != t.width || img.height != t.height || img.channels <= 0)
        fail(file, line, fmt::format("texture '{}' changed while the scene was read", name));
      fill_rgb(t, img, name, file, line, &clamped);
    }
    return it->second;
  }

  // A regular file within the size limit (OpenImageIO would block on a FIFO, read a device for ever).
  if (auto problem = file_problem(ref.real, ctx.opts.max_file_bytes))
    fail(file, line, fmt::format("texture '{}' {}", name, *problem));
  {
    // Check the size before read_image allocates it.
    auto in = OIIO::ImageInput::open(ref.real.string());
    if (!in) fail(file, line, fmt::format("cannot read texture '{}': {}", name, OIIO::geterror()));
    const OIIO::ImageSpec& spec = in->spec();
    const double pixels = double(std::max(spec.width, 0)) * double(std::max(spec.height, 0));
    if (pixels + double(ctx.texture_pixels) > double(ctx.opts.max_texture_pixels))
      fail(file, line,
           fmt::format("texture '{}' has {} x {} pixels: the scene's textures exceed the limit of {} pixels", name,
                       spec.width, spec.height, ctx.opts.max_texture_pixels));
    if (spec.nchannels < 1 || spec.nchannels > 16)
      fail(file, line, fmt::format("texture '{}' has {} channels", name, spec.nchannels));
    in->close();
  }
  Texture t;
  t.path = name;
  size_t clamped = 0;
  if (use == TextureUse::kColour || data) {
    Image img;
    try {
      img = read_image(ref.real.string(), !data);
    } catch (const std::exception& e) {
      fail(file, line, fmt::format("cannot read texture '{}': {}", name, e.what()));
    }
    if (img.width <= 0 || img.height <= 0 || img.channels <= 0 ||
        img.data.size() != size_t(img.width) * size_t(img.height) * size_t(img.channels))
      fail(file, line, fmt::format("texture '{}' is empty or malformed", name));
    t.width = img.width;
    t.height = img.height;
    fill_rgb(t, img, name, file, line, &clamped);
  } else {
    auto in = OIIO::ImageInput::open(ref.real.string());
    if (!in || in->spec().width <= 0 || in->spec().height <= 0)
      fail(file, line, fmt::format("texture '{}' is empty or malformed", name));
    t.width = in->spec().width;
    t.height = in->spec().height;
    in->close();
    t.alpha = read_mask(ref.real.string(), use, name, file, line);
  }
  ctx.texture_pixels += size_t(t.width) * size_t(t.height);
  ctx.textures.push_back(std::move(t));
  if (clamped > 0 && !data)
    warn(ctx.report, fmt::format("{}:{}: texture '{}': {} values outside [0, 1] clamped (it is a diffuse albedo)", file,
                                 line, name, clamped));
  record_file(ref, &ctx.report);
  const int index = int(ctx.textures.size() - 1);
  if (!data) ctx.texture_of_path.emplace(ref.real, index);
  return index;
}

}  // namespace epr::loader
