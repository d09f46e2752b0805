#include "master/result_files.h"

#include <fmt/format.h>
#include <stdio.h>
#include <tbb/task_group.h>

#include <algorithm>
#include <cerrno>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <system_error>

#include "common/checked_file.h"

namespace epr {
namespace fs = std::filesystem;

Image samples_heat_map(const Image& mprime) {
  float max_m = 0;
  for (float v : mprime.data) max_m = std::max(max_m, v);
  return heat_map(mprime, max_m);
}

namespace {

// The combined, path-traced and reprojected images are noise at the sample counts rendered here: zip
// made them ~4 % smaller for ~0.6 CPU-s per 1920 x 1080 image, the largest part of writing a finished
// job's files, so they are written uncompressed. The counts and M' images, which zip shrinks 5x, keep it.
constexpr const char* kNoisyImageCompression = "none";

void write_kind(const ResultKindInfo& k, const FrameImages& img, const nlohmann::json& stats, const std::string& path) {
  switch (k.kind) {
    case ResultKind::kExr:
      write_exr(path, combined_image(img), kNoisyImageCompression);
      return;
    case ResultKind::kPng:
      write_png_srgb(path, combined_image(img));
      return;
    case ResultKind::kPathtrace:
      write_exr(path, pathtrace_image(img), kNoisyImageCompression);
      return;
    case ResultKind::kCounts:
      write_exr(path, counts_image(img));
      return;
    case ResultKind::kReprojection:
      write_exr(path, img.reprojection, kNoisyImageCompression);
      return;
    case ResultKind::kSamplesExr:
      write_exr(path, img.reprojected);
      return;
    case ResultKind::kSamplesPng:
      write_png_srgb(path, samples_heat_map(img.reprojected));
      return;
    case ResultKind::kJson:
      write_file_checked(path, stats.dump(2) + "\n");
      return;
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
      return bytes(encode_png_srgb(combined_image(images)));
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
      // Renamed into place only once written whole and fsynced: a failed write (a full disk) leaves
      // no file under the final name, and the temp file is removed.
      const fs::path final_path(path);
      const fs::path tmp = final_path.parent_path() / (".tmp-" + final_path.filename().string());
      try {
        write_kind(k, images, stats, tmp.string());
        if (::rename(tmp.c_str(), final_path.c_str()) != 0)
          throw std::system_error(errno, std::generic_category(),
                                  fmt::format("cannot rename '{}' to '{}'", tmp.string(), final_path.string()));
      } catch (...) {
        std::error_code ec;
        fs::remove(tmp, ec);
        throw;
      }
    });
  }
  files.wait();  // rethrows what a write threw
}

}  // namespace epr
