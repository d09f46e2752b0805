// Environment images (environment.h): read through OpenImageIO inside the scene's folder.
#include "common/scene_loader/environment.h"

#include <OpenImageIO/imageio.h>
#include <fmt/format.h>

#include <cmath>
#include <filesystem>
#include <memory>

#include "common/image.h"
#include "common/limits.h"
#include "common/scene_loader/path_sandbox.h"
#include "common/scene_loader/text.h"

namespace epr::loader {

void load_environment_image(EnvironmentLight& e, const std::string& folder, const std::string& where,
                            LoadReport* report) {
  namespace fs = std::filesystem;
  const LoadOptions limits;
  if (folder.empty())
    throw SceneError(
        fmt::format("{}: environment image '{}': a built-in scene has no folder to read it from; name "
                    "it in a scene JSON beside the image, e.g. {{\"builtin\": \"cornell\", "
                    "\"environment\": {{\"image\": \"{}\"}}}}",
                    where, e.image, fs::path(e.image).filename().string()));
  const fs::path root(folder);
  const FileRef ref = resolve_inside(root, root, "", e.image, where, 0, "environment image");
  if (auto problem = file_problem(ref.real, limits.max_file_bytes))
    throw SceneError(fmt::format("{}: environment image '{}' {}", where, e.image, *problem));
  {
    auto in = OIIO::ImageInput::open(ref.real.string());
    if (!in)
      throw SceneError(fmt::format("{}: cannot read environment image '{}': {}", where, e.image, OIIO::geterror()));
    const OIIO::ImageSpec& spec = in->spec();
    if (double(spec.width) * double(spec.height) > double(limits.max_texture_pixels) || spec.width < 1 ||
        spec.height < 1 || spec.nchannels < 1 || spec.nchannels > 16)
      throw SceneError(fmt::format("{}: environment image '{}' has {} x {} pixels and {} channels: at most {} pixels",
                                   where, e.image, spec.width, spec.height, spec.nchannels, limits.max_texture_pixels));
  }
  Image img;
  try {
    img = read_image(ref.real.string());
  } catch (const std::exception& ex) {
    throw SceneError(fmt::format("{}: cannot read environment image '{}': {}", where, e.image, ex.what()));
  }
  if (img.width <= 0 || img.height <= 0 ||
      img.data.size() != size_t(img.width) * size_t(img.height) * size_t(img.channels))
    throw SceneError(fmt::format("{}: environment image '{}' is empty or malformed", where, e.image));
  // Real HDR captures carry small negative values (noise of the capture's processing): 0, as Cycles
  // shows them. Values above limits::kMaxColour (+inf included) are capped as colours are. NaN has no
  // meaning and is refused.
  auto rgb = std::make_shared<Image>(img.width, img.height, 3);
  size_t negative = 0, capped = 0;
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      Vec3 c = img.rgb(x, y);
      for (int k = 0; k < 3; ++k) {
        if (std::isnan(c[k]))
          throw SceneError(fmt::format("{}: environment image '{}' has a NaN texel at ({}, {})", where, e.image, x, y));
        if (c[k] < 0) ++negative, c[k] = 0;
        if (c[k] > limits::kMaxColour) ++capped, c[k] = limits::kMaxColour;
      }
      rgb->set_rgb(x, y, c);
    }
  const auto note = [&](const std::string& text) {
    const std::string message = fmt::format("{}: environment image '{}': {}", where, e.image, text);
    if (report)
      warn(*report, message);
    else
      scene_log()->debug("{}", message);
  };
  if (negative > 0) note(fmt::format("{} negative texel values read as 0", negative));
  if (capped > 0)
    note(fmt::format("{} texel values above {:g} (or infinite) capped to {:g}", capped, limits::kMaxColour,
                     limits::kMaxColour));
  e.pixels = std::move(rgb);
  if (report) record_file(ref, report);
}

}  // namespace epr::loader
