// The GL and CPU back-ends decide every vertex alike: a FrameState of each, given the same scene and
// the same vertices, ends its round with the same decision counts, per-subpixel counts, M' and skip
// mask. The vertices: traced paths (CheckpointStreamed's input), random points, points on subpixel
// borders with their neighbours 1 and 2 ulps away (some on either side), and points at texel centres
// where the GL rasteriser and the CPU builder pick different triangles (an edge through the centre).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "common/vertex_codec.h"
#include "master/deep_framebuffer.h"
#include "master/frame_state.h"
#include "master/gl_context.h"
#include "master/plane_grid_builder.h"
#include "master/reprojection_kernel.h"
#include "tests/master/test_scenes.h"
#include "tests/master/traced_vertices.h"

namespace epr {
namespace {

// Texels whose plane differs between the two builders' grids.
size_t builders_disagree(const detail::PlaneGrid& a, const detail::PlaneGrid& b) {
  size_t n = 0;
  for (size_t t = 0; t < a.texel_plane.size(); ++t) {
    const uint32_t pa = a.texel_plane[t], pb = b.texel_plane[t];
    if (pa == detail::PlaneGrid::kUncovered || pb == detail::PlaneGrid::kUncovered) {
      n += pa != pb;
      continue;
    }
    for (int c = 0; c < 4; ++c)
      if (a.planes[4 * size_t(pa) + c] != b.planes[4 * size_t(pb) + c]) {
        ++n;
        break;
      }
  }
  return n;
}

// The records of v[first, end) again, each coordinate of the position moved 1 and 2 ulps either way;
// returns how many of the originals have copies landing in more than one texel (a border crossed).
size_t add_ulp_neighbours(std::vector<VertexRecord>& v, size_t first, const Camera& camera, int subpixels) {
  const detail::KernelParams k = detail::make_kernel_params(camera, subpixels, 0.f);
  const size_t end = v.size();
  size_t crossing = 0;
  for (size_t i = first; i < end; ++i) {
    const VertexRecord r = v[i];
    std::vector<uint32_t> texels;
    for (int axis = 0; axis < 3; ++axis)
      for (int steps : {-2, -1, 1, 2}) {
        VertexRecord q = r;
        float* c = axis == 0 ? &q.position.x : axis == 1 ? &q.position.y : &q.position.z;
        for (int s = 0; s < std::abs(steps); ++s) *c = std::nextafter(*c, steps < 0 ? -1e30f : 1e30f);
        v.push_back(q);
        uint32_t texel = 0;
        if (detail::project_and_face(k, q.position, q.normal, &texel) == detail::Decision::kAccepted)
          texels.push_back(texel);
      }
    std::sort(texels.begin(), texels.end());
    crossing += std::unique(texels.begin(), texels.end()) - texels.begin() > 1;
  }
  return crossing;
}

class BackendDecisions : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(gl_available()) << "OSMesa unavailable: run scripts/setup.sh (libosmesa6)";
    ctx_ = std::make_unique<GlContext>();
  }

  void run(const std::string& scene_name, int w, int h, int subpixels, uint32_t seed) {
    const Scene scene = test::scene_named(scene_name);
    const Camera camera(scene.camera, w, h);
    RenderOptions o;
    o.width = w;
    o.height = h;
    o.spp = 16;
    o.paths_per_round = 4;
    o.mode = RenderMode::kSkip;
    o.subpixels = subpixels;
    o.min_paths = 1;
    const float epsilon = o.epsilon * scene.bounds().diagonal_length();
    const float tolerance = epsilon * detail::kCreaseToleranceFraction;

    // The builders disagree somewhere, so the vertices below exercise it.
    const detail::PlaneGrid by_gl = detail::build_plane_grid(scene, camera, subpixels, tolerance, true, ctx_.get());
    const detail::PlaneGrid by_cpu = detail::build_plane_grid(scene, camera, subpixels, tolerance, true, nullptr);
    const size_t disagree = builders_disagree(by_gl, by_cpu);
    EXPECT_GT(disagree, 0u) << "no texel where the builders differ: the test would not see the cause";

    std::mt19937 rng(seed);
    std::vector<VertexRecord> v = test::traced_vertices(scene, camera, seed, subpixels);
    const size_t traced = v.size();
    ASSERT_GT(traced, 500u);
    test::add_random_points(scene, 20000, rng, v);
    const DeepFramebuffer dfb_gl = build_deep_framebuffer_gl(*ctx_, scene, camera, subpixels);
    const DeepFramebuffer dfb_cpu = build_deep_framebuffer_cpu(scene, camera, subpixels);
    for (const DeepFramebuffer* dfb : {&dfb_gl, &dfb_cpu}) {
      const size_t border = v.size();
      test::add_boundary_points(*dfb, camera, 5000, rng, v);
      EXPECT_GT(add_ulp_neighbours(v, border, camera, subpixels), 50u) << "border points that straddle the border";
      test::add_visible_points(*dfb, camera, 20000, 0.f, rng, v);  // on the texel centres' hits
      // Both hits at every texel the builders disagree on: one builder's point is on the other's
      // neighbouring surface.
      for (size_t t = 0; t < dfb->texel_count(); ++t) {
        const bool differ = dfb_gl.covered[t] != dfb_cpu.covered[t] ||
                            (dfb_gl.covered[t] && (dfb_gl.normal_at(t) != dfb_cpu.normal_at(t) ||
                                                   dfb_gl.plane_offset[t] != dfb_cpu.plane_offset[t]));
        if (!differ || !dfb->covered[t]) continue;
        VertexRecord r;
        r.position = dfb->position_at(t);
        r.normal = dfb->normal_at(t);
        if (dot(r.normal, camera.eye() - r.position) < 0) r.normal = -r.normal;
        r.radiance = {1, 2, 3};
        r.flags = VertexRecord::kDiffuse;
        v.push_back(r);
      }
    }
    const VertexCodec codec(scene.bounds());
    std::string packed;
    codec.encode_batch(v, &packed);

    // GL on the caller's context (the master), CPU with and without it (the master; `epr render`).
    std::vector<std::unique_ptr<FrameState>> frames;
    for (auto [method, gl] : {std::pair{ReprojectMethod::kGl, ctx_.get()}, std::pair{ReprojectMethod::kCpu, ctx_.get()},
                              std::pair{ReprojectMethod::kCpu, static_cast<GlContext*>(nullptr)}}) {
      RenderOptions oo = o;
      oo.reproject = method;
      frames.push_back(std::make_unique<FrameState>(oo, camera, scene, gl));
      FrameState& f = *frames.back();
      f.reproject(v);              // float records
      f.reproject_packed(packed);  // the wire's 16-byte records
      f.finish_round();
    }
    const FrameSnapshot ref = frames[0]->save();
    const ReprojectionCounts c = ref.counts;
    EXPECT_GT(c.accepted, v.size() / 4);
    EXPECT_GT(c.occluded - c.backfacing, v.size() / 50);
    EXPECT_GT(c.culled, v.size() / 100);
    for (size_t i = 1; i < frames.size(); ++i) {
      SCOPED_TRACE("frame " + std::to_string(i) + " against GL's; builders disagree on " + std::to_string(disagree) +
                   " texels");
      const FrameSnapshot s = frames[i]->save();
      EXPECT_EQ(s.counts, ref.counts);  // accepted, culled, backfacing, occluded ... one by one
      EXPECT_EQ(s.counts.accepted, ref.counts.accepted);
      EXPECT_EQ(s.counts.occluded, ref.counts.occluded);
      size_t subpixels_differ = 0, pixels_differ = 0;
      ASSERT_EQ(s.accumulation.count.size(), ref.accumulation.count.size());
      for (size_t k = 0; k < ref.accumulation.count.size(); ++k)
        subpixels_differ += s.accumulation.count[k] != ref.accumulation.count[k];
      for (size_t p = 0; p < ref.mprime.size(); ++p) pixels_differ += s.mprime[p] != ref.mprime[p];
      EXPECT_EQ(subpixels_differ, 0u) << "subpixels whose counts differ";
      EXPECT_EQ(pixels_differ, 0u) << "pixels whose M' differs";
      EXPECT_EQ(s.skip, ref.skip);
    }
  }
  std::unique_ptr<GlContext> ctx_;
};

// CheckpointStreamed.FrameWrittenFromTheLiveStateRestoresBitIdentically's frame.
TEST_F(BackendDecisions, CornellSmallFrameAtTwoSubpixels) { run("cornell", 24, 16, 2, 1); }
TEST_F(BackendDecisions, CornellAtFourSubpixels) { run("cornell", 64, 64, 4, 2); }
TEST_F(BackendDecisions, HallAtFourSubpixels) { run("hall", 80, 45, 4, 3); }

}  // namespace
}  // namespace epr
