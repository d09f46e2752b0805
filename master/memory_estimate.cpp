#include "master/memory_estimate.h"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>

namespace epr {

MemoryEstimate estimate_job_memory(const RenderOptions& opts, bool checkpoints) {
  const uint64_t w = uint64_t(std::max(0, opts.width)), h = uint64_t(std::max(0, opts.height));
  const uint64_t s = uint64_t(std::max(1, opts.subpixels));
  const uint64_t pixels = w * h;
  const bool reprojects = opts.mode != RenderMode::kPathTrace;
  MemoryEstimate e;
  // FrameState: path sums (3 doubles), M (4), M' (8), L_rp (3 floats), skip (1).
  constexpr uint64_t kFrameStatePerPixel = 24 + 4 + 8 + 12 + 1;
  // The finished job's images: FrameImages (3 RGB + 2 one-channel floats = 44 B), images()'s sum
  // image (12), one encoder's temporaries (the counts image 8, the heat map 12, a PNG's rows ~4 B),
  // and the preview copy (44) still held while the results are written.
  constexpr uint64_t kResultsPerPixel = 44 + 12 + 8 + 12 + 4;
  constexpr uint64_t kPreviewPerPixel = 44;
  e.pixel_bytes = pixels * (kFrameStatePerPixel + kResultsPerPixel + kPreviewPerPixel);
  if (reprojects) {
    const uint64_t texels = pixels * s * s;
    e.subpixel_bytes = texels * (16 + 4);
    const uint64_t rows = std::min(h * s, kDeepFramebufferBuildRows);
    e.build_bytes = w * s * rows * kDeepFramebufferBuildBytesPerTexel;
  }
  // A checkpoint copies the frame (FrameSnapshot: the accumulation and the per-pixel arrays) and
  // encodes it (about as large again) while the job goes on.
  if (checkpoints) e.checkpoint_bytes = 2 * (pixels * kFrameStatePerPixel + (reprojects ? pixels * s * s * 16 : 0));
  return e;
}

uint64_t physical_memory_bytes() {
  const long pages = ::sysconf(_SC_PHYS_PAGES), page = ::sysconf(_SC_PAGE_SIZE);
  uint64_t bytes = pages > 0 && page > 0 ? uint64_t(pages) * uint64_t(page) : 0;
  // A container's limit (cgroup v2, else v1), when it is below the machine's.
  for (const char* path : {"/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"}) {
    std::ifstream in(path);
    std::string v;
    if (!(in >> v) || v.empty() || !std::isdigit(static_cast<unsigned char>(v[0]))) continue;
    try {
      const uint64_t limit = std::stoull(v);
      if (limit > 0 && (bytes == 0 || limit < bytes)) bytes = limit;
    } catch (const std::exception&) {
    }
    break;
  }
  return bytes;
}

uint64_t default_memory_budget() { return uint64_t(double(physical_memory_bytes()) * kDefaultBudgetFraction); }

std::optional<uint64_t> parse_byte_size(const std::string& text) {
  size_t used = 0;
  double v;
  try {
    v = std::stod(text, &used);
  } catch (const std::exception&) {
    return std::nullopt;
  }
  std::string unit = text.substr(used);
  for (char& c : unit) c = char(std::toupper(static_cast<unsigned char>(c)));
  double scale = 1;
  if (!unit.empty() && unit != "B") {
    const std::string units = "KMGT";
    const size_t k = units.find(unit[0]);
    if (k == std::string::npos) return std::nullopt;
    const std::string rest = unit.substr(1);
    if (!(rest.empty() || rest == "B" || rest == "I" || rest == "IB")) return std::nullopt;
    scale = std::pow(1024.0, double(k + 1));
  }
  const double bytes = v * scale;
  if (!std::isfinite(bytes) || bytes < 1 || bytes >= 1.8e19) return std::nullopt;
  return uint64_t(bytes);
}

std::string format_gib(uint64_t bytes) { return fmt::format("{:.2f} GiB", double(bytes) / double(1ull << 30)); }

std::optional<std::string> memory_budget_error(const RenderOptions& opts, bool checkpoints, uint64_t budget) {
  if (budget == 0) return std::nullopt;
  const uint64_t need = estimate_job_memory(opts, checkpoints).total();
  if (need <= budget) return std::nullopt;
  return fmt::format("a {}x{} frame at S={} needs {} of master memory; the budget is {}", opts.width, opts.height,
                     opts.mode == RenderMode::kPathTrace ? 1 : opts.subpixels, format_gib(need), format_gib(budget));
}

}  // namespace epr
