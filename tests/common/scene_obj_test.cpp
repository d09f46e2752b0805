// The OBJ reader (common/scene_loader/obj.cpp) builds the mesh from the tokens it validates: these
// tests pin the scenes it builds bit for bit. The OBJ-level messages and limits are in
// scene_loader_test.cpp.
#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <random>
#include <string>

#include "common/builtin_scenes.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "tests/common/scene_test_files.h"

namespace epr {
namespace {

const std::string kCornellDir = EPR_SOURCE_DIR "/scenes/cornell-box";

/// FNV-1a over the bytes of everything a scene's geometry and materials are made of.
class Fingerprint {
 public:
  void add(const void* data, size_t n) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (size_t i = 0; i < n; ++i) hash_ = (hash_ ^ p[i]) * 0x100000001b3ull;
  }
  template <class T>
  void add_vector(const std::vector<T>& v) {
    const uint64_t n = v.size();
    add(&n, sizeof n);
    if (n > 0) add(v.data(), v.size() * sizeof(T));
  }
  uint64_t value() const { return hash_; }

 private:
  uint64_t hash_ = 0xcbf29ce484222325ull;
};

uint64_t fingerprint(const Scene& s) {
  Fingerprint f;
  f.add_vector(s.positions);
  f.add_vector(s.triangles);
  f.add_vector(s.material_of);
  f.add_vector(s.uvs);
  for (const Material& m : s.materials) {
    f.add(m.name.data(), m.name.size() + 1);
    f.add(&m.kd, sizeof m.kd);
    f.add(&m.ke, sizeof m.ke);
    f.add(&m.kd_texture, sizeof m.kd_texture);
  }
  return f.value();
}

bool same_bits(const Vec3& a, const Vec3& b) { return std::memcmp(&a, &b, sizeof(Vec3)) == 0; }

// The built-in box is generated from the OBJ's numbers and split along the same diagonals: the same
// triangles bit for bit, each with its corners in the same cyclic order and the same material (the
// generator lists a quad's two triangles in another order and may start them at another corner).
TEST(SceneObj, CornellObjHasTheBuiltinCornellsTrianglesBitForBit) {
  const Scene obj = load_obj(kCornellDir + "/CornellBox-Original.obj");
  const Scene builtin = make_builtin_scene("cornell");
  ASSERT_EQ(obj.triangle_count(), builtin.triangle_count());
  auto corner = [](const Scene& s, size_t tri, size_t k) { return s.positions[s.triangles[tri][k % 3]]; };
  auto same_triangle = [&](size_t t, size_t u) {
    for (size_t r = 0; r < 3; ++r)
      if (same_bits(corner(obj, t, 0), corner(builtin, u, r)) &&
          same_bits(corner(obj, t, 1), corner(builtin, u, r + 1)) &&
          same_bits(corner(obj, t, 2), corner(builtin, u, r + 2)))
        return obj.material_of[t] == builtin.material_of[u];
    return false;
  };
  std::vector<bool> used(builtin.triangle_count(), false);
  for (size_t t = 0; t < obj.triangle_count(); ++t) {
    size_t u = 0;
    while (u < used.size() && (used[u] || !same_triangle(t, u))) ++u;
    ASSERT_LT(u, used.size()) << "OBJ triangle " << t << " is not a built-in triangle";
    used[u] = true;
  }
  ASSERT_EQ(obj.materials.size(), builtin.materials.size());
  for (size_t i = 0; i < obj.materials.size(); ++i) {
    EXPECT_EQ(obj.materials[i].name, builtin.materials[i].name);
    EXPECT_TRUE(same_bits(obj.materials[i].kd, builtin.materials[i].kd)) << obj.materials[i].name;
    EXPECT_TRUE(same_bits(obj.materials[i].ke, builtin.materials[i].ke)) << obj.materials[i].name;
  }
}

/// An OBJ with two MTL files that exercises the reader: numbers as exporters write them ("%.6f"),
/// shortest floats, exponents and signs; texture coordinates; faces of 3 to 12 corners, convex and
/// concave, some folded, with absolute, relative, v/vt and v//vn corners; usemtl switches (to a
/// name no library defines, too) and a second mtllib. Integer arithmetic on std::mt19937's output
/// (fixed by the standard) keeps the text the same everywhere.
struct GeneratedObj {
  std::string obj, mtl_a, mtl_b;
};

GeneratedObj generated_obj() {
  std::mt19937 rng(20240611);
  auto below = [&](uint32_t n) { return rng() % n; };
  auto coordinate = [&]() -> std::string {
    const double x = (double(below(2000001)) - 1000000.0) / 100000.0;  // -10 .. 10
    switch (below(5)) {
      case 0:
        return fmt::format("{:.6f}", x);
      case 1:
        return fmt::format("{}", float(x));
      case 2:
        return fmt::format("{:e}", x * 1e-3);
      case 3:
        return fmt::format("{}", int(x));
      default:
        return fmt::format("{:.9g}", x / 7.0);
    }
  };
  // Unit directions of a 12-gon, 4 decimals: polygons without trigonometry.
  static const double kDir[12][2] = {{1, 0},  {0.866, 0.5},   {0.5, 0.866},   {0, 1},  {-0.5, 0.866}, {-0.866, 0.5},
                                     {-1, 0}, {-0.866, -0.5}, {-0.5, -0.866}, {0, -1}, {0.5, -0.866}, {0.866, -0.5}};
  GeneratedObj g;
  g.mtl_a = "newmtl red\nKd 0.63 0.065 0.05\nnewmtl glow\nKd 0.78\nKe 17 12 4\nnewmtl red\nKd 0.1 0.1 0.1\n";
  g.mtl_b = "newmtl white\nKd 0.725 0.71 0.68\nNs 10\nnewmtl grey\nKd 0.5\n";
  std::string& o = g.obj;
  o = "mtllib a.mtl\n";
  size_t nv = 0, nvt = 0;
  static const char* kMaterials[] = {"red", "glow", "white", "grey", "missing"};
  for (int face = 0; face < 400; ++face) {
    if (face == 200) o += "mtllib b.mtl\n";
    if (below(8) == 0) o += fmt::format("usemtl {}\n", kMaterials[below(5)]);
    const uint32_t n = below(3) == 0 ? 3 + below(2) : 5 + below(8);
    const double cx = double(below(200)) / 10.0, cy = double(below(200)) / 10.0, cz = double(below(200)) / 10.0;
    const uint32_t plane = below(3), shape = below(4);
    for (uint32_t k = 0; k < n; ++k) {
      const uint32_t d = k * 12 / n;
      double r = 1.0;
      if (shape == 1) r = k % 2 ? 0.4 : 1.0;                  // star: concave
      if (shape == 2) r = 0.25 + double(below(100)) / 100.0;  // irregular, maybe folded
      const double u = r * kDir[d][0], v = r * kDir[d][1];
      const double p[3] = {cx + (plane == 0 ? u : 0.0), cy + (plane == 1 ? 0.0 : v), cz + (plane == 0 ? 0.0 : u)};
      if (shape == 3)
        o += fmt::format("v {} {} {}\n", coordinate(), coordinate(), coordinate());
      else
        o += fmt::format("v {:.6f} {} {}\n", p[0], float(p[1]), p[2]);
    }
    nv += n;
    const bool uv = below(2) == 0;
    if (uv) {
      for (uint32_t k = 0; k < n; ++k) o += fmt::format("vt {:.4f} {}\n", double(below(10000)) / 10000.0, k % 2);
      nvt += n;
    }
    o += "f";
    const bool relative = below(4) == 0;
    for (uint32_t k = 0; k < n; ++k) {
      const long v = relative ? long(k) - long(n) : long(nv - n + k + 1);
      const long t = relative ? long(k) - long(n) : long(nvt - n + k + 1);
      o += uv ? fmt::format(" {}/{}", v, t) : (below(5) == 0 ? fmt::format(" {}//1", v) : fmt::format(" {}", v));
    }
    o += "\n";
  }
  return {"vn 0 0 1\n" + g.obj, g.mtl_a, g.mtl_b};
}

// The expected values are the fingerprints of the scenes tinyobjloader 2.0.0rc10 (float build)
// gives for the same files: numbers, triangulation and material tables are that library's.
TEST(SceneObj, CornellObjLoadsToItsFingerprint) {
  const Scene s = load_obj(kCornellDir + "/CornellBox-Original.obj");
  EXPECT_EQ(fingerprint(s), 0xdd54a5152b22f48aull) << std::hex << fingerprint(s);
}

TEST(SceneObj, GeneratedObjLoadsToItsFingerprint) {
  set_log_level("error");
  test::TempDir dir;
  const GeneratedObj g = generated_obj();
  dir.write("a.mtl", g.mtl_a);
  dir.write("b.mtl", g.mtl_b);
  const Scene s = load_obj(dir.write("generated.obj", g.obj));
  set_log_level("info");
  EXPECT_GT(s.triangle_count(), 1000u);
  EXPECT_EQ(s.materials.size(), 6u);  // red glow red (a.mtl), white grey (b.mtl), default
  EXPECT_EQ(fingerprint(s), 0xac500ca3fc47e1abull) << std::hex << fingerprint(s);
}

}  // namespace
}  // namespace epr
