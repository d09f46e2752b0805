// See edge_pixels.h.
#include "master/edge_pixels.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>

#include "master/deep_framebuffer.h"

namespace epr::detail {

namespace {

// Whether two plane-table entries hold the same plane (a creased entry copies its own plane).
bool same_entry_plane(const PlaneGrid& g, uint32_t a, uint32_t b) {
  if (a == b) return true;
  if (a == PlaneGrid::kUncovered || b == PlaneGrid::kUncovered) return false;
  return same_plane(&g.planes[4 * size_t(a)], &g.planes[4 * size_t(b)]);
}

// The plane grid's surfaces as the plane test sees them.
struct Surfaces {
  const PlaneGrid& g;
  const Camera& camera;
  float epsilon;

  uint32_t entry(int gx, int gy) const { return g.texel_plane[size_t(gy) * size_t(g.width) + size_t(gx)]; }
  // The point of entry e's plane on the ray through texel (gx, gy)'s centre, false if parallel.
  bool point_on(uint32_t e, int gx, int gy, Vec3* x) const {
    const float* q = &g.planes[4 * size_t(e)];
    const int S = g.subpixels;
    const Ray r = camera.generate_ray((float(gx) + 0.5f) / float(S), (float(gy) + 0.5f) / float(S));
    const Vec3 n{q[0], q[1], q[2]};
    const float along = dot(n, r.dir);
    if (!(std::fabs(along) > 0)) return false;
    *x = r.origin + r.dir * ((q[3] - dot(n, r.origin)) / along);
    return true;
  }
  float distance(uint32_t e, const Vec3& x) const {
    const float* q = &g.planes[4 * size_t(e)];
    return std::fabs(q[0] * x.x + q[1] * x.y + q[2] * x.z - q[3]);
  }
  bool within(uint32_t e, const Vec3& x) const { return distance(e, x) <= epsilon; }
  // Whether covered texels a (entry ea, its point pa when has_pa) and b see one surface: one plane,
  // or each texel's point within epsilon of the other's plane (facets of one flat or gently curved
  // surface), as the plane test would accept it. Computes *pa on first need.
  bool same(uint32_t ea, int ax, int ay, Vec3* pa, bool* has_pa, uint32_t eb, int bx, int by) const {
    if (same_entry_plane(g, ea, eb)) return true;
    if (!*has_pa && !point_on(ea, ax, ay, pa)) return false;
    *has_pa = true;
    Vec3 pb;
    return point_on(eb, bx, by, &pb) && within(ea, pb) && within(eb, *pa);
  }
};

constexpr int kMaxClasses = 64;  // S <= 8

// What the supersampled visibility makes of an edge pixel.
enum class Resolved : uint8_t { kEdge, kOneSurface, kWeighted };

}  // namespace

EdgePixels::EdgePixels(const PlaneGrid& g, const Camera& camera, float epsilon, const Scene* scene,
                       const CoherentRays& rays) {
  const auto start = std::chrono::steady_clock::now();
  const int S = g.subpixels;
  width_ = S > 0 ? g.width / S : 0;
  height_ = S > 0 ? g.height / S : 0;
  const size_t pixels = size_t(width_) * size_t(height_);
  bits_.assign((pixels + 63) / 64, 0);
  const Surfaces surf{g, camera, epsilon};
  // Is pixel p an edge pixel? A pixel that sees no surface at all is not (it gets no samples anyway).
  const auto edge = [&](size_t p) {
    const int x = int(p % size_t(width_)), y = int(p / size_t(width_));
    const int gx0 = std::max(0, x * S - 1), gx1 = std::min(g.width, (x + 1) * S + 1);
    const int gy0 = std::max(0, y * S - 1), gy1 = std::min(g.height, (y + 1) * S + 1);
    const uint32_t first = surf.entry(gx0, gy0);
    Vec3 first_point;
    bool have_first_point = false;
    for (int gy = gy0; gy < gy1; ++gy)
      for (int gx = gx0; gx < gx1; ++gx) {
        const uint32_t e = surf.entry(gx, gy);
        if (first == PlaneGrid::kUncovered || e == PlaneGrid::kUncovered) {
          if (e != first) return true;
          continue;
        }
        if (!surf.same(first, gx0, gy0, &first_point, &have_first_point, e, gx, gy)) return true;
      }
    return false;
  };
  // One task per run of 64-pixel words: each word is written by one task only.
  tbb::parallel_for(tbb::blocked_range<size_t>(0, bits_.size(), 64), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t w = r.begin(); w != r.end(); ++w)
      for (size_t p = w * 64; p < std::min(pixels, w * 64 + 64); ++p)
        if (edge(p)) bits_[w] |= uint64_t(1) << (p & 63);
  });
  if (scene && S >= 1 && S * S <= kMaxClasses) resolve(g, camera, epsilon, *scene, rays);
  for (uint64_t word : bits_) count_ += size_t(__builtin_popcountll(word));
  seconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

void EdgePixels::resolve(const PlaneGrid& g, const Camera& camera, float epsilon, const Scene& scene,
                         const CoherentRays& trace) {
  const int S = g.subpixels, k = rays_per_texel(S);
  const size_t pixels = size_t(width_) * size_t(height_);
  std::vector<uint32_t> edges;
  for (size_t p = 0; p < pixels; ++p)
    if ((*this)[p]) edges.push_back(uint32_t(p));
  if (edges.empty()) return;
  const Surfaces surf{g, camera, epsilon};
  std::unique_ptr<EmbreeBvh> bvh;
  CoherentRays rays = trace;
  if (!rays) {
    bvh = std::make_unique<EmbreeBvh>(scene);
    rays = [&bvh](std::span<const Ray> r, std::span<const float> tnear, std::span<Hit> hits) {
      bvh->intersect_coherent(r, tnear, hits);
    };
  }
  // The deep framebuffer's near plane (kNearPlane): a ray sees what lies beyond `near` along the view
  // direction, from tnear = near / cos(ray, view direction) on.
  const float near = kNearPlane * scene.bounds().diagonal_length();
  const size_t per_pixel = size_t(S) * size_t(S), rays_per_pixel = per_pixel * size_t(k) * size_t(k);
  std::vector<Resolved> resolved(edges.size(), Resolved::kEdge);
  std::vector<uint16_t> codes(edges.size() * per_pixel);
  struct Batch {
    std::vector<Ray> rays;
    std::vector<float> tnear;
    std::vector<Hit> hits;
  };
  tbb::enumerable_thread_specific<Batch> batches;
  tbb::parallel_for(size_t(0), edges.size(), [&](size_t i) {
    const int x = int(edges[i] % uint32_t(width_)), y = int(edges[i] / uint32_t(width_));
    // The surface classes of the texel centres: per class its first texel (entry, position, point).
    uint32_t rep[kMaxClasses];
    int rep_x[kMaxClasses], rep_y[kMaxClasses];
    Vec3 rep_point[kMaxClasses];
    bool rep_has_point[kMaxClasses];
    int texel_class[kMaxClasses];
    int classes = 0;
    for (int j = 0; j < S; ++j)
      for (int ii = 0; ii < S; ++ii) {
        const int gx = x * S + ii, gy = y * S + j;
        const uint32_t e = surf.entry(gx, gy);
        if (e == PlaneGrid::kUncovered) return;
        int c = 0;
        while (c < classes && !surf.same(rep[c], rep_x[c], rep_y[c], &rep_point[c], &rep_has_point[c], e, gx, gy)) ++c;
        if (c == classes) {
          rep[c] = e, rep_x[c] = gx, rep_y[c] = gy, rep_has_point[c] = false;
          ++classes;
        }
        texel_class[j * S + ii] = c;
      }
    // The supersampled visibility: k x k rays per texel, traced together (ray r of texel t at index
    // t * k * k + r, texels row by row), each counted for the class of its own texel if its hit lies
    // within epsilon of that texel's plane (what the plane test accepts there), else for that of the
    // pixel's texel whose plane is nearest, within epsilon.
    Batch& b = batches.local();
    b.rays.resize(rays_per_pixel), b.tnear.resize(rays_per_pixel), b.hits.resize(rays_per_pixel);
    size_t n = 0;
    for (int gy = y * S; gy < (y + 1) * S; ++gy)
      for (int gx = x * S; gx < (x + 1) * S; ++gx)
        for (int fy = 0; fy < k; ++fy)
          for (int fx = 0; fx < k; ++fx, ++n) {
            b.rays[n] = camera.generate_ray((float(gx) + (float(fx) + 0.5f) / float(k)) / float(S),
                                            (float(gy) + (float(fy) + 0.5f) / float(k)) / float(S));
            b.tnear[n] = near / dot(b.rays[n].dir, camera.forward());
          }
    rays(b.rays, b.tnear, b.hits);
    int area[kMaxClasses] = {};
    bool emitter = false;
    for (size_t r = 0; r < rays_per_pixel; ++r) {
      const Hit& h = b.hits[r];
      if (h.prim == EmbreeBvh::kMissed) return;
      emitter = emitter || scene.materials[scene.material_of[h.prim]].emissive();
      const Vec3 hit = b.rays[r].origin + b.rays[r].dir * h.t;
      const int own = int(r / (size_t(k) * size_t(k)));
      int best = -1;
      if (surf.within(surf.entry(x * S + own % S, y * S + own / S), hit)) {
        best = texel_class[own];
      } else {
        float best_distance = INFINITY;
        for (int t = 0; t < S * S; ++t) {
          const float d = surf.distance(surf.entry(x * S + t % S, y * S + t / S), hit);
          if (d <= epsilon && d < best_distance) best = texel_class[t], best_distance = d;
        }
      }
      if (best < 0) return;
      ++area[best];
    }
    // An emitter beside another surface: the contrast magnifies what the weights leave (the
    // unsampled strip along the boundary), so such a pixel keeps tracing its own paths.
    if (classes > 1 && emitter) return;
    if (classes == 1) {
      resolved[i] = Resolved::kOneSurface;
      return;
    }
    for (size_t s = 0; s < per_pixel; ++s)
      codes[i * per_pixel + s] = AreaWeights::pack(texel_class[s], area[texel_class[s]]);
    resolved[i] = Resolved::kWeighted;
  });
  size_t weighted = 0;
  for (size_t i = 0; i < edges.size(); ++i) {
    if (resolved[i] == Resolved::kEdge) continue;
    bits_[edges[i] >> 6] &= ~(uint64_t(1) << (edges[i] & 63));
    if (resolved[i] != Resolved::kWeighted) continue;
    weights_.pixels.push_back(edges[i]);
    std::copy_n(codes.begin() + std::ptrdiff_t(i * per_pixel), per_pixel,
                codes.begin() + std::ptrdiff_t(weighted * per_pixel));
    ++weighted;
  }
  codes.resize(weighted * per_pixel);
  codes.shrink_to_fit();
  weights_.cells = std::move(codes);
}

void EdgePixels::drop(PixelReprojection* out) const {
  if (count_ == 0) return;
  const size_t pixels = size_t(width_) * size_t(height_);
  const bool radiance = out->radiance.width == width_ && out->radiance.height == height_;
  for (size_t w = 0; w < bits_.size(); ++w) {
    uint64_t word = bits_[w];
    while (word) {
      const size_t p = w * 64 + size_t(__builtin_ctzll(word));
      word &= word - 1;
      if (p >= pixels) break;
      if (out->count.size() == pixels) out->count[p] = 0;
      if (out->effective.size() == pixels) out->effective[p] = 0.f;
      if (out->half_variance.size() == 2 * pixels) {
        for (size_t k = 0; k < 2; ++k) {
          for (size_t c = 0; c < 3; ++c) out->half_radiance[6 * p + 3 * k + c] = 0.f;
          out->half_effective[2 * p + k] = 0.f;
          out->half_variance[2 * p + k] = -1.f;
          out->half_subpixels[2 * p + k] = 0;
        }
      }
      if (radiance) out->radiance.set_rgb(int(p % size_t(width_)), int(p / size_t(width_)), Vec3(0.f));
    }
  }
}

}  // namespace epr::detail
