// Kd textures named by map_Kd: read through OpenImageIO inside the scene folder, once per file,
// checked against the size limits before they are decoded, clamped to [0, 1] (they are albedos).
#include <OpenImageIO/imageio.h>
#include <fmt/format.h>

#include <algorithm>
#include <system_error>

#include "common/image.h"
#include "common/scene_loader/obj_context.h"
#include "common/scene_loader/text.h"

namespace epr::loader {
namespace {

namespace fs = std::filesystem;

Texture to_texture(const Image& img, const std::string& name, const std::string& file, size_t line, size_t* clamped) {
  Texture t;
  t.path = name;
  t.width = img.width;
  t.height = img.height;
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
  return t;
}

}  // namespace

int load_texture(ObjContext& ctx, const std::string& name, const fs::path& dir, const std::string& display_dir,
                 const std::string& file, size_t line) {
  std::string portable = name;
  std::replace(portable.begin(), portable.end(), '\\', '/');  // textures named on Windows
  const FileRef ref = resolve_inside(ctx.root, dir, display_dir, portable, file, line, "texture");
  if (auto it = ctx.texture_of_path.find(ref.real); it != ctx.texture_of_path.end()) return it->second;

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
  Image img;
  try {
    img = read_image(ref.real.string());
  } catch (const std::exception& e) {
    fail(file, line, fmt::format("cannot read texture '{}': {}", name, e.what()));
  }
  if (img.width <= 0 || img.height <= 0 || img.channels <= 0 ||
      img.data.size() != size_t(img.width) * size_t(img.height) * size_t(img.channels))
    fail(file, line, fmt::format("texture '{}' is empty or malformed", name));
  size_t clamped = 0;
  ctx.texture_pixels += size_t(img.width) * size_t(img.height);
  ctx.textures.push_back(to_texture(img, name, file, line, &clamped));
  if (clamped > 0)
    warn(ctx.report, fmt::format("{}:{}: texture '{}': {} values outside [0, 1] clamped (it is a diffuse albedo)", file,
                                 line, name, clamped));
  record_file(ref, &ctx.report);
  const int index = int(ctx.textures.size() - 1);
  ctx.texture_of_path.emplace(ref.real, index);
  return index;
}

}  // namespace epr::loader
