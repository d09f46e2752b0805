#include "master/server/previews.h"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iterator>

#include "common/image.h"
#include "common/log.h"
#include "common/result_kinds.h"
#include "master/result_files.h"

namespace epr {
namespace fs = std::filesystem;

bool is_preview_layer(std::string_view layer) {
  return std::find(kPreviewLayers.begin(), kPreviewLayers.end(), layer) != kPreviewLayers.end();
}

std::optional<std::vector<unsigned char>> encode_preview(const FrameImages& img, bool reprojects,
                                                         std::string_view layer) {
  if (layer == "combined") return encode_png_srgb(img.combined);
  if (layer == "pathtrace") return encode_png_srgb(img.pathtrace);
  if (!reprojects) return std::nullopt;
  if (layer == "reprojection") return encode_png_srgb(img.reprojection);
  if (layer == "samples") return encode_png_srgb(samples_heat_map(img.reprojected));
  return std::nullopt;
}

std::optional<std::vector<unsigned char>> result_preview(const std::string& dir, std::string_view layer) {
  auto stored = [&](ResultKind k) { return fs::path(dir) / result_kind(k).stored_as; };
  auto bytes = [](const fs::path& p) -> std::optional<std::vector<unsigned char>> {
    std::ifstream in(p, std::ios::binary);
    if (!in) return std::nullopt;
    return std::vector<unsigned char>(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  };
  try {
    if (layer == "combined") return bytes(stored(ResultKind::kPng));
    if (layer == "samples") return bytes(stored(ResultKind::kSamplesPng));
    if (layer == "pathtrace" || layer == "reprojection") {
      const fs::path exr = stored(layer == "pathtrace" ? ResultKind::kPathtrace : ResultKind::kReprojection);
      if (!fs::exists(exr)) return std::nullopt;
      return encode_png_srgb(read_image(exr.string()));
    }
  } catch (const std::exception& e) {
    logger("master")->warn("preview {} from {}: {}", layer, dir, e.what());
  }
  return std::nullopt;
}

}  // namespace epr
