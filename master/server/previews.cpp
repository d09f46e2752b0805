#include "master/server/previews.h"

#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <charconv>
#include <filesystem>
#include <fstream>
#include <iterator>

#include "common/log.h"
#include "common/result_kinds.h"
#include "master/result_files.h"

namespace epr {
namespace fs = std::filesystem;
namespace {

struct Key {
  std::string_view layer;
  int max_side = kPreviewMaxSide;
};

std::optional<Key> parse_key(std::string_view key) {
  Key k;
  const size_t at = key.find('@');
  k.layer = key.substr(0, at);
  if (!is_preview_layer(k.layer)) return std::nullopt;
  if (at != std::string_view::npos) {
    auto bound = parse_preview_bound(key.substr(at + 1));
    if (!bound) return std::nullopt;
    k.max_side = *bound;
  }
  return k;
}

// The heat map of M' at the preview's size, coloured against the largest M' of the whole image so
// that a downscaled heat map means what the full one does.
Image samples_preview(const Image& mprime, int k) {
  if (k <= 1) return samples_heat_map(mprime);
  float max_m = 0;
  for (float v : mprime.data) max_m = std::max(max_m, v);
  return heat_map(box_downscale(mprime, k), max_m);
}

std::vector<unsigned char> encode_scaled(const Image& img, int max_side) {
  const int k = preview_factor(img.width, img.height, max_side);
  return encode_png_srgb(k > 1 ? box_downscale(img, k) : img);
}

// Width and height of an image file from its header (OpenImageIO); {0, 0} if it cannot be read.
std::pair<int, int> image_size(const fs::path& p) {
  auto in = OIIO::ImageInput::open(p.string());
  if (!in) {
    (void)OIIO::geterror();
    return {0, 0};
  }
  return {in->spec().width, in->spec().height};
}

}  // namespace

bool is_preview_layer(std::string_view layer) {
  return std::find(kPreviewLayers.begin(), kPreviewLayers.end(), layer) != kPreviewLayers.end();
}

std::optional<int> parse_preview_bound(std::string_view text) {
  if (text.empty() || text.size() > 9) return std::nullopt;
  int v = 0;
  auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc() || end != text.data() + text.size() || v <= 0) return std::nullopt;
  v = std::clamp(v, kPreviewMinBound, kPreviewMaxBound);
  int p = kPreviewMinBound;
  while (p * 2 <= v) p *= 2;
  return p;
}

std::string preview_key(std::string_view layer, int max_side) {
  std::string key(layer);
  if (max_side != kPreviewMaxSide) {
    key += '@';
    key += std::to_string(max_side);
  }
  return key;
}

int preview_factor(int width, int height, int max_side) {
  const int longest = std::max(width, height);
  if (max_side <= 0 || longest <= max_side) return 1;
  return (longest + max_side - 1) / max_side;
}

Image box_downscale(const Image& img, int k) {
  if (k <= 1) return img;
  const int c = img.channels;
  Image out((img.width + k - 1) / k, (img.height + k - 1) / k, c);
  std::vector<double> sum(size_t(out.width) * size_t(c));
  for (int oy = 0; oy < out.height; ++oy) {
    std::fill(sum.begin(), sum.end(), 0.0);
    const int y0 = oy * k, y1 = std::min(img.height, y0 + k);
    for (int y = y0; y < y1; ++y) {
      const float* row = img.at(0, y);
      for (int x = 0; x < img.width; ++x) {
        double* s = &sum[size_t(x / k) * size_t(c)];
        for (int ch = 0; ch < c; ++ch) s[ch] += double(row[size_t(x) * size_t(c) + size_t(ch)]);
      }
    }
    for (int ox = 0; ox < out.width; ++ox) {
      const int n = (std::min(img.width, (ox + 1) * k) - ox * k) * (y1 - y0);
      float* o = out.at(ox, oy);
      for (int ch = 0; ch < c; ++ch) o[ch] = float(sum[size_t(ox) * size_t(c) + size_t(ch)] / double(n));
    }
  }
  return out;
}

std::optional<std::vector<unsigned char>> encode_preview(const FrameImages& img, bool reprojects,
                                                         std::string_view key) {
  const auto k = parse_key(key);
  if (!k) return std::nullopt;
  if (k->layer == "combined") return encode_scaled(combined_image(img), k->max_side);
  if (k->layer == "pathtrace") return encode_scaled(pathtrace_image(img), k->max_side);
  if (!reprojects) return std::nullopt;
  if (k->layer == "reprojection") return encode_scaled(img.reprojection, k->max_side);
  if (k->layer == "samples")
    return encode_png_srgb(
        samples_preview(img.reprojected, preview_factor(img.reprojected.width, img.reprojected.height, k->max_side)));
  return std::nullopt;
}

std::optional<std::vector<unsigned char>> result_preview(const std::string& dir, std::string_view key) {
  const auto k = parse_key(key);
  if (!k) return std::nullopt;
  auto stored = [&](ResultKind kind) { return fs::path(dir) / result_kind(kind).stored_as; };
  auto bytes = [](const fs::path& p) -> std::optional<std::vector<unsigned char>> {
    std::ifstream in(p, std::ios::binary);
    if (!in) return std::nullopt;
    return std::vector<unsigned char>(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  };
  // The stored PNG as it is when it fits the bound; otherwise the float image, downscaled.
  auto fits = [&](const fs::path& png) {
    const auto [w, h] = image_size(png);
    return w > 0 && preview_factor(w, h, k->max_side) == 1;
  };
  try {
    if (k->layer == "combined" || k->layer == "samples") {
      const bool combined = k->layer == "combined";
      const fs::path png_path = stored(combined ? ResultKind::kPng : ResultKind::kSamplesPng);
      auto png = bytes(png_path);
      if (!png || fits(png_path)) return png;
      const fs::path exr = stored(combined ? ResultKind::kExr : ResultKind::kSamplesExr);
      if (!fs::exists(exr)) return png;  // nothing to downscale from: the stored PNG as it is
      const Image img = read_image(exr.string());
      const int f = preview_factor(img.width, img.height, k->max_side);
      return encode_png_srgb(combined ? box_downscale(img, f) : samples_preview(img, f));
    }
    if (k->layer == "pathtrace" || k->layer == "reprojection") {
      const fs::path exr = stored(k->layer == "pathtrace" ? ResultKind::kPathtrace : ResultKind::kReprojection);
      if (!fs::exists(exr)) return std::nullopt;
      return encode_scaled(read_image(exr.string()), k->max_side);
    }
  } catch (const std::exception& e) {
    logger("master")->warn("preview {} from {}: {}", key, dir, e.what());
  }
  return std::nullopt;
}

}  // namespace epr
