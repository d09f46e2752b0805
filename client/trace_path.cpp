#include "client/trace_path.h"

#include <fmt/format.h>

#include <charconv>
#include <stdexcept>
#include <vector>

#include "common/denormals.h"
#include "common/scene_loader.h"
#include "worker/path_tracer.h"

namespace epr {
namespace {

std::string vec(const Vec3& v) { return fmt::format("{:.9g} {:.9g} {:.9g}", v.x, v.y, v.z); }

template <typename T>
bool parse_number(std::string_view s, T* v) {
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), *v);
  return ec == std::errc() && end == s.data() + s.size() && !s.empty();
}

}  // namespace

std::optional<PathRef> parse_path_ref(const std::string& text, std::string* why) {
  const size_t a = text.find(','), b = a == std::string::npos ? a : text.find(',', a + 1);
  PathRef r;
  const std::string_view s(text);
  if (b == std::string::npos || !parse_number(s.substr(0, a), &r.x) ||
      !parse_number(s.substr(a + 1, b - a - 1), &r.y) || !parse_number(s.substr(b + 1), &r.sample) || r.x < 0 ||
      r.y < 0) {
    *why = "expected X,Y,SAMPLE (pixel column, row and sample index, numbers from 0), got '" + text + "'";
    return std::nullopt;
  }
  return r;
}

bool trace_path(const RenderOptions& opts, const PathRef& ref, std::FILE* out) {
  if (ref.x >= opts.width || ref.y >= opts.height)
    throw std::invalid_argument(
        fmt::format("--trace-path: pixel {},{} is outside the {}x{} image", ref.x, ref.y, opts.width, opts.height));
  const Scene scene = load_job_scene(opts.scene, {}, nullptr, opts.lighting, opts.env_folder);
  const Camera camera(opts.camera_for(scene.camera), opts.width, opts.height);
  const EmbreeScene embree(scene);
  const SkyLight sky(scene.lighting, embree);
  const PathTracer tracer(embree, camera, opts.seed, opts.rr, opts.mis, opts.sampler, &sky);

  const ScopedFlushDenormals flush_denormals;  // as the tile renderer traces
  std::vector<VertexRecord> records;
  PathStats stats;
  const Vec3 radiance = tracer.trace_unfiltered(ref.x, ref.y, ref.sample, &records, &stats);
  const bool finite = is_finite(radiance);
  fmt::print(out, "seed {} pixel {},{} sample {}: radiance {}{}\n", opts.seed, ref.x, ref.y, ref.sample, vec(radiance),
             finite ? "" : ", non-finite: a render drops this sample");
  fmt::print(out, "vertices {} rays {} recorded {}\n", stats.vertices, stats.rays, records.size());
  for (size_t i = 0; i < records.size(); ++i) {
    const VertexRecord& v = records[i];
    fmt::print(out, "x{}: position {} normal {} radiance {}{}\n", i + 2, vec(v.position), vec(v.normal),
               vec(v.radiance), v.diffuse() ? "" : " (not diffuse)");
  }
  return finite;
}

}  // namespace epr
