// The scene model: "model no more than a scene needs" (DESIGN.md section 2).
//
// Triangles with flat geometric normals, one material per triangle. Materials are Lambertian
// (constant Kd or a Kd texture), optionally emissive (a diffuse area light of radiance Ke, emitting
// from both sides as Cycles' mesh lights do), or the one glossy material that exists only to test
// the method's failure mode. No scene graph, no instancing, no shading normals.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "common/camera.h"
#include "common/math.h"

namespace epr {

enum class MaterialType : uint8_t {
  kDiffuse,  // Lambertian: f = Kd / pi
  kGlossy,   // Kd / pi + normalised Phong lobe: Ks (n + 2) / (2 pi) cos^n(alpha)
};

struct Material {
  std::string name;
  MaterialType type = MaterialType::kDiffuse;
  Vec3 kd{0.8f};           // diffuse albedo, linear RGB in [0, 1]
  int kd_texture = -1;     // index into Scene::textures, replaces kd when >= 0
  Vec3 ke{0.f};            // emitted radiance, W / (m^2 sr) per channel; non-zero makes an emitter
  Vec3 ks{0.f};            // glossy albedo (kGlossy only)
  float exponent = 100.f;  // Phong exponent (kGlossy only)

  bool emissive() const { return !is_black(ke); }
  bool diffuse() const { return type == MaterialType::kDiffuse; }
};

/// A linear-RGB float image sampled with wrapping texture coordinates, nearest texel.
struct Texture {
  std::string path;  // as named in the MTL file, for messages
  int width = 0, height = 0;
  std::vector<float> rgb;  // width * height * 3, row 0 is the top (v = 1)

  Vec3 lookup(Vec2 uv) const;
};

struct Scene {
  std::string name;                                // file name or builtin:NAME
  std::vector<Vec3> positions;                     // world space, metres
  std::vector<std::array<uint32_t, 3>> triangles;  // indices into positions
  std::vector<uint32_t> material_of;               // per triangle, index into materials
  std::vector<std::array<Vec2, 3>> uvs;            // per triangle corner; empty if untextured
  std::vector<Material> materials;
  std::vector<Texture> textures;
  CameraSpec camera;

  size_t triangle_count() const { return triangles.size(); }
  Bounds3 bounds() const;
  /// Checks indices, finite coordinates and materials; throws std::runtime_error with the reason.
  void validate() const;
  Vec3 geometric_normal(size_t tri) const;  // unit length, right-hand rule on the corner order
  float area(size_t tri) const;
};

/// Appends a triangle with material `mat` (and corner uvs if the scene is textured).
void add_triangle(Scene& s, Vec3 a, Vec3 b, Vec3 c, uint32_t mat);
/// Appends the quad a-b-c-d (counter-clockwise seen from the front) as two triangles.
void add_quad(Scene& s, Vec3 a, Vec3 b, Vec3 c, Vec3 d, uint32_t mat);
/// Appends a quad split into n x n cells (2 n^2 triangles): the tessellation knob of built-ins.
void add_tessellated_quad(Scene& s, Vec3 a, Vec3 b, Vec3 c, Vec3 d, uint32_t mat, int n);
uint32_t add_material(Scene& s, Material m);

}  // namespace epr
