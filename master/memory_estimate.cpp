#include "master/memory_estimate.h"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>
#include <iterator>

namespace epr {

MemoryEstimate estimate_job_memory(const RenderOptions& opts, bool checkpoints) {
  const uint64_t w = uint64_t(std::max(0, opts.width)), h = uint64_t(std::max(0, opts.height));
  const uint64_t s = uint64_t(std::max(1, opts.subpixels));
  const uint64_t pixels = w * h;
  const bool reprojects = opts.mode != RenderMode::kPathTrace;
  MemoryEstimate e;
  // FrameState: path sums (3 floats), M (4), M' (4), skip (1).
  constexpr uint64_t kFrameStatePerPixel = 12 + 4 + 4 + 1;
  // The round: its plan (skip 1) and the tile results queued (3 floats + a count).
  constexpr uint64_t kRoundPerPixel = 1 + 16;
  // One set of images (FrameImages: path sums and L_rp in RGB, M and M' in one channel; the preview
  // copy is dropped before the next is made).
  constexpr uint64_t kImagesPerPixel = 12 + 12 + 4 + 4;
  e.pixel_bytes = pixels * (kFrameStatePerPixel + kRoundPerPixel + kImagesPerPixel);
  if (reprojects && opts.combine == CombineRule::kVariance) {
    // The variance combination (master/combine_rule.h): FrameState's B per half (2 floats), M'_eff and
    // the even rounds' path sums (3 floats); a downsampling's M'_eff, L_rp,h (6 floats), M'_eff,h, v_rp,h
    // (2 floats each) and n_h (2 bytes); the combined estimate (3 floats).
    constexpr uint64_t kVariancePerPixel = (8 + 4 + 12) + (4 + 24 + 8 + 8 + 2) + 12;
    e.pixel_bytes += pixels * kVariancePerPixel;
  }
  if (reprojects) {
    const uint64_t texels = pixels * s * s;
    e.subpixel_bytes = texels * (16 + 2);
    e.build_bytes = texels * kBuildIndexBytesPerTexel + std::min(kBuildBandBytes, texels * kBuildBandBytesPerTexel);
    // A small frame's rounds do not fill it: at most ~16 vertices of 16 bytes per pixel are queued.
    e.queue_bytes = std::min(kCommitQueueBytes, pixels * 16 * 16);
  }
  if (checkpoints) e.checkpoint_bytes = kCheckpointBytes;
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

std::string format_byte_size(uint64_t bytes) {
  static constexpr const char* kUnits[] = {"KiB", "MiB", "GiB", "TiB"};
  if (bytes < 1024) return fmt::format("{} bytes", bytes);
  double v = double(bytes) / 1024;
  size_t u = 0;
  while (u + 1 < std::size(kUnits) && v >= 1024) {
    v /= 1024;
    ++u;
  }
  return fmt::format("{:.2f} {}", v, kUnits[u]);
}

uint64_t frames_memory(const RenderOptions& opts, bool checkpoints, uint32_t frames) {
  const MemoryEstimate e = estimate_job_memory(opts, checkpoints);
  return uint64_t(frames) * (e.total() - e.queue_bytes) + e.queue_bytes;
}

std::optional<std::string> memory_budget_error(const RenderOptions& opts, bool checkpoints, uint64_t budget,
                                               uint32_t frames) {
  if (budget == 0) return std::nullopt;
  const uint64_t need = frames_memory(opts, checkpoints, std::max<uint32_t>(frames, 1));
  if (need <= budget) return std::nullopt;
  const std::string what = frames > 1 ? fmt::format("a window run of {} {}x{} frames", frames, opts.width, opts.height)
                                      : fmt::format("a {}x{} frame", opts.width, opts.height);
  return fmt::format("{} at S={} needs {} of master memory; the budget is {}{}", what,
                     opts.mode == RenderMode::kPathTrace ? 1 : opts.subpixels, format_byte_size(need),
                     format_byte_size(budget), frames > 1 ? " (submit shorter runs: epr submit --window-run)" : "");
}

}  // namespace epr
