#include "master/result_files.h"

#include <fmt/format.h>
#include <tbb/task_group.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace epr {
namespace fs = std::filesystem;

Image samples_heat_map(const Image& mprime) {
  float max_m = 0;
  for (float v : mprime.data) max_m = std::max(max_m, v);
  return heat_map(mprime, max_m);
}

namespace {

// An RGB float image as an uncompressed scanline OpenEXR file (OpenEXR 2, single part). The
// combined, path-traced and reprojected images are noise at the sample counts rendered here: zip
// made them ~4 % smaller for ~0.6 CPU-s per 1920 x 1080 image, the largest part of writing a
// finished job's files. (The counts and M' images, which zip shrinks 5x, keep write_exr.)
void write_exr_rgb_uncompressed(const std::string& path, const Image& img) {
  if (img.channels != 3 || img.width <= 0 || img.height <= 0) throw std::invalid_argument("not an RGB image");
  std::string h;
  auto i32 = [&](int32_t v) { h.append(reinterpret_cast<const char*>(&v), 4); };
  auto f32 = [&](float v) { h.append(reinterpret_cast<const char*>(&v), 4); };
  auto attr = [&](const char* name, const char* type, int32_t size) {
    h += name;
    h += '\0';
    h += type;
    h += '\0';
    i32(size);
  };
  static_assert(std::endian::native == std::endian::little);
  i32(20000630);  // magic
  i32(2);         // version 2, single-part scanline
  attr("channels", "chlist", 3 * (2 + 16) + 1);
  for (const char* c : {"B", "G", "R"}) {  // sorted by name, as OpenEXR stores them
    h += c;
    h += '\0';
    i32(2);             // FLOAT
    h.append(4, '\0');  // pLinear, reserved
    i32(1), i32(1);     // x and y sampling
  }
  h += '\0';
  attr("compression", "compression", 1);
  h += '\0';  // NO_COMPRESSION
  for (const char* window : {"dataWindow", "displayWindow"}) {
    attr(window, "box2i", 16);
    i32(0), i32(0), i32(img.width - 1), i32(img.height - 1);
  }
  attr("lineOrder", "lineOrder", 1);
  h += '\0';  // INCREASING_Y
  attr("pixelAspectRatio", "float", 4);
  f32(1);
  attr("screenWindowCenter", "v2f", 8);
  f32(0), f32(0);
  attr("screenWindowWidth", "float", 4);
  f32(1);
  h += '\0';  // end of the header
  // The offset table (one scanline per chunk), then the chunks: y, size, the B, G and R rows.
  const uint64_t row_bytes = uint64_t(img.width) * 3 * 4, chunk_bytes = 8 + row_bytes;
  const uint64_t first = h.size() + 8 * uint64_t(img.height);
  for (int y = 0; y < img.height; ++y) {
    const uint64_t offset = first + uint64_t(y) * chunk_bytes;
    h.append(reinterpret_cast<const char*>(&offset), 8);
  }
  std::ofstream out(path, std::ios::binary);
  out.write(h.data(), std::streamsize(h.size()));
  std::vector<char> chunk(chunk_bytes);
  std::vector<float> row(size_t(img.width) * 3);
  for (int y = 0; y < img.height && out; ++y) {
    const float* src = img.at(0, y);
    for (int c = 0; c < 3; ++c)
      for (int x = 0; x < img.width; ++x) row[size_t(c) * size_t(img.width) + size_t(x)] = src[3 * x + (2 - c)];
    const int32_t yy = y, size = int32_t(row_bytes);
    std::memcpy(chunk.data(), &yy, 4);
    std::memcpy(chunk.data() + 4, &size, 4);
    std::memcpy(chunk.data() + 8, row.data(), row_bytes);
    out.write(chunk.data(), std::streamsize(chunk.size()));
  }
  if (!out.flush()) throw std::runtime_error(fmt::format("cannot write image '{}'", path));
}

void write_kind(const ResultKindInfo& k, const FrameImages& img, const nlohmann::json& stats, const std::string& path) {
  switch (k.kind) {
    case ResultKind::kExr:
      write_exr_rgb_uncompressed(path, img.combined);
      return;
    case ResultKind::kPng:
      write_png_srgb(path, img.combined);
      return;
    case ResultKind::kPathtrace:
      write_exr_rgb_uncompressed(path, img.pathtrace);
      return;
    case ResultKind::kCounts:
      write_exr(path, counts_image(img));
      return;
    case ResultKind::kReprojection:
      write_exr_rgb_uncompressed(path, img.reprojection);
      return;
    case ResultKind::kSamplesExr:
      write_exr(path, img.reprojected);
      return;
    case ResultKind::kSamplesPng:
      write_png_srgb(path, samples_heat_map(img.reprojected));
      return;
    case ResultKind::kJson: {
      std::ofstream out(path);
      out << stats.dump(2) << "\n";
      if (!out.flush()) throw std::runtime_error(fmt::format("cannot write '{}'", path));
      return;
    }
  }
}

std::string read_bytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  if (!in) throw std::runtime_error(fmt::format("cannot read '{}'", path.string()));
  return ss.str();
}

}  // namespace

std::string encode_result(const ResultKindInfo& k, const FrameImages& images, const nlohmann::json& stats,
                          const std::string& scratch_path) {
  auto bytes = [](const std::vector<unsigned char>& v) { return std::string(v.begin(), v.end()); };
  switch (k.kind) {
    case ResultKind::kJson:
      return stats.dump(2) + "\n";
    case ResultKind::kPng:
      return bytes(encode_png_srgb(images.combined));
    case ResultKind::kSamplesPng:
      return bytes(encode_png_srgb(samples_heat_map(images.reprojected)));
    default:
      break;
  }
  struct Remove {
    const std::string& path;
    ~Remove() {
      std::error_code ec;
      fs::remove(path, ec);
    }
  } remove{scratch_path};
  write_kind(k, images, stats, scratch_path);
  return read_bytes(scratch_path);
}

void write_results(const FrameImages& images, bool reprojects, const nlohmann::json& stats,
                   const std::function<std::string(const ResultKindInfo&)>& path_of) {
  // Encoded side by side: on the master the workers idle until the job is done.
  tbb::task_group files;
  for (const ResultKindInfo& k : result_kinds()) {
    if (k.needs_reprojection && !reprojects) continue;
    const std::string path = path_of(k);
    if (path.empty()) continue;
    files.run([&k, &images, &stats, path] {
      // The temp name keeps the extension, which OpenImageIO picks the format by.
      const fs::path final_path(path);
      const fs::path tmp = final_path.parent_path() / (".tmp-" + final_path.filename().string());
      write_kind(k, images, stats, tmp.string());
      fs::rename(tmp, final_path);
    });
  }
  files.wait();  // rethrows what a write threw
}

}  // namespace epr
