// Textures named by map_Kd (colour) and map_d or a glTF MASK material (alpha masks): read through
// OpenImageIO inside the scene folder, one Texture per file. load_texture checks a file and its header
// against the size limits and notes what its uses need; decode_textures decodes all of them at the end
// of the load, in parallel (texels() decodes one earlier, for a load that reads its texels). Colour is
// clamped to [0, 1] (it is an albedo); a mask is read as stored (alpha is not sRGB-encoded), and only
// files used as masks keep one.
#include <OpenImageIO/imageio.h>
#include <fmt/format.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <exception>
#include <system_error>

#include "common/image.h"
#include "common/scene_loader/obj_context.h"
#include "common/scene_loader/text.h"

namespace epr::loader {
namespace {

namespace fs = std::filesystem;

/// The image's RGB as a texture's colour, clamped to [0, 1]; *clamped counts the values that were not.
std::vector<float> clamped_rgb(const Image& img, const PendingTexels& p, size_t* clamped) {
  std::vector<float> rgb(size_t(img.width) * size_t(img.height) * 3);
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      const Vec3 c = img.rgb(x, y);
      if (!is_finite(c)) fail(p.file, p.line, fmt::format("texture '{}' has non-finite texels", p.name));
      float* out = &rgb[(size_t(y) * size_t(img.width) + size_t(x)) * 3];
      for (int k = 0; k < 3; ++k) {
        const float v = std::clamp(c[k], 0.f, 1.f);
        if (v != c[k]) ++*clamped;
        out[k] = v;
      }
    }
  return rgb;
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

/// Decodes what `p` asks for and t lacks into t (whose size is the header's); returns how many colour
/// values were clamped. Throws SceneError naming the file that referred to the texture.
size_t decode(Texture& t, const PendingTexels& p) {
  const size_t pixels = size_t(t.width) * size_t(t.height);
  size_t clamped = 0;
  if ((p.colour || p.data) && t.rgb.empty()) {
    Image img;
    try {
      img = read_image(p.ref.real.string(), !p.data);
    } catch (const std::exception& e) {
      fail(p.file, p.line, fmt::format("cannot read texture '{}': {}", p.name, e.what()));
    }
    if (img.width != t.width || img.height != t.height || img.channels <= 0)
      fail(p.file, p.line, fmt::format("texture '{}' changed while the scene was read", p.name));
    if (img.data.size() != pixels * size_t(img.channels))
      fail(p.file, p.line, fmt::format("texture '{}' is empty or malformed", p.name));
    t.rgb = clamped_rgb(img, p, &clamped);
  }
  if (p.mask != TextureUse::kColour && t.alpha.empty()) {
    t.alpha = read_mask(p.ref.real.string(), p.mask, p.name, p.file, p.line);
    if (t.alpha.size() != pixels)
      fail(p.file, p.line, fmt::format("texture '{}' changed while the scene was read", p.name));
  }
  return clamped;
}

void warn_clamped(ObjContext& ctx, const PendingTexels& p, size_t clamped) {
  if (clamped > 0 && !p.data)
    warn(ctx.report, fmt::format("{}:{}: texture '{}': {} values outside [0, 1] clamped (it is a diffuse albedo)",
                                 p.file, p.line, p.name, clamped));
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
    PendingTexels& p = ctx.pending[it->second];
    if (use == TextureUse::kColour)
      p.colour = true;
    else if (p.mask == TextureUse::kColour)
      p.mask = use;
    p.done = false;
    return it->second;
  }

  // A regular file within the size limit (OpenImageIO would block on a FIFO, read a device for ever).
  if (auto problem = file_problem(ref.real, ctx.opts.max_file_bytes))
    fail(file, line, fmt::format("texture '{}' {}", name, *problem));
  Texture t;
  t.path = name;
  {
    // Check the size before anything is decoded.
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
    if (spec.width <= 0 || spec.height <= 0) fail(file, line, fmt::format("texture '{}' is empty or malformed", name));
    t.width = spec.width;
    t.height = spec.height;
    in->close();
  }
  ctx.texture_pixels += size_t(t.width) * size_t(t.height);
  ctx.textures.push_back(std::move(t));
  record_file(ref, &ctx.report);
  const int index = int(ctx.textures.size() - 1);
  PendingTexels& p = ctx.pending[index];
  p.ref = ref;
  p.name = name;
  p.file = file;
  p.line = line;
  p.colour = use == TextureUse::kColour;
  p.data = data;
  if (use == TextureUse::kMask || use == TextureUse::kAlpha) p.mask = use;
  if (!data) ctx.texture_of_path.emplace(ref.real, index);
  return index;
}

const Texture& texels(ObjContext& ctx, int index) {
  Texture& t = ctx.textures[size_t(index)];
  auto it = ctx.pending.find(index);
  if (it != ctx.pending.end() && !it->second.done) {
    warn_clamped(ctx, it->second, decode(t, it->second));
    it->second.done = true;
  }
  return t;
}

void decode_textures(ObjContext& ctx) {
  std::vector<std::pair<Texture*, PendingTexels*>> todo;
  for (auto& [index, p] : ctx.pending)
    if (!p.done) todo.emplace_back(&ctx.textures[size_t(index)], &p);
  if (!ctx.opts.decode_textures) {
    for (auto& [t, p] : todo) t->header_only = true;
    return;
  }
  // The largest first, so that no large one is left for the end; each task writes its own texture.
  std::stable_sort(todo.begin(), todo.end(), [](const auto& a, const auto& b) {
    return size_t(a.first->width) * size_t(a.first->height) > size_t(b.first->width) * size_t(b.first->height);
  });
  std::vector<size_t> clamped(todo.size(), 0);
  std::vector<std::exception_ptr> errors(todo.size());
  tbb::parallel_for(
      tbb::blocked_range<size_t>(0, todo.size(), 1),
      [&](const tbb::blocked_range<size_t>& r) {
        for (size_t k = r.begin(); k != r.end(); ++k) try {
            clamped[k] = decode(*todo[k].first, *todo[k].second);
          } catch (...) {
            errors[k] = std::current_exception();
          }
      },
      tbb::simple_partitioner());
  // Errors and warnings in the textures' order, whichever thread decoded them.
  std::vector<size_t> order(todo.size());
  for (size_t k = 0; k < order.size(); ++k) order[k] = k;
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return todo[a].first < todo[b].first; });
  for (size_t k : order)
    if (errors[k]) std::rethrow_exception(errors[k]);
  for (size_t k : order) {
    warn_clamped(ctx, *todo[k].second, clamped[k]);
    todo[k].second->done = true;
  }
}

}  // namespace epr::loader
