// The scene model: "model no more than a scene needs" (DESIGN.md section 2).
//
// Triangles with geometric normals and, where the scene gives them, per-corner shading normals
// (smooth shading) and normal maps (common/shading_normal.h), one material per triangle. Materials are Lambertian
// (constant Kd or a Kd texture), optionally emissive (a diffuse area light of radiance Ke, emitting
// from both sides as Cycles' mesh lights do, or from the front side only, as a real light panel and
// pbrt's and Mitsuba's area lights do), or the one glossy material that exists only to test
// the method's failure mode, or glTF's metallic-roughness material on a GGX microfacet model (metals,
// dielectrics with a specular layer, glass: worker/bsdf_ggx.h). A material may be cut out by an alpha
// mask: where the mask's texel is below the cut-off the surface is not there (rays pass through). No
// scene graph, no instancing.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "common/camera.h"
#include "common/lighting.h"
#include "common/lights.h"
#include "common/math.h"

namespace epr {

enum class MaterialType : uint8_t {
  kDiffuse,     // Lambertian: f = Kd / pi
  kGlossy,      // Kd / pi + normalised Phong lobe: Ks (n + 2) / (2 pi) cos^n(alpha)
  kMicrofacet,  // glTF metallic-roughness on GGX (worker/bsdf_ggx.h); Kd is the base colour
};

struct Material {
  std::string name;
  MaterialType type = MaterialType::kDiffuse;
  Vec3 kd{0.8f};                  // diffuse albedo, linear RGB in [0, 1]
  int kd_texture = -1;            // index into Scene::textures, replaces kd when >= 0
  Vec3 ke{0.f};                   // emitted radiance, W / (m^2 sr) per channel; non-zero makes an emitter
  bool emits_front_only = false;  // Ke leaves the front side only (the right-hand-rule normal's side)
  Vec3 ks{0.f};                   // glossy albedo (kGlossy only)
  float exponent = 100.f;         // Phong exponent (kGlossy only)
  int alpha_texture = -1;         // index into Scene::textures (its alpha): a cut-out when >= 0
  float alpha_cutoff = 0.5f;      // where the mask's alpha is below this the surface is a hole
  int normal_texture = -1;        // index into Scene::textures: a tangent-space normal map (linear data) when >= 0
  float normal_scale = 1.f;       // multiplies the map's x and y (glTF normalTexture.scale)
  // kMicrofacet only: glTF's factors (alpha = roughness^2), linear. With a texture (>= 0) they
  // multiply its G (roughness) and B (metallic) channels, which hold data: the texture is the image
  // as decoded for colour, and the sRGB curve is re-applied per lookup (exact for 8- and 16-bit
  // images up to float rounding).
  float metallic = 0, roughness = 1, transmission = 0, ior = 1.5f;
  int metallic_roughness_texture = -1;
  int ke_texture = -1;  // multiplies Ke per texel when >= 0 (its mean is 1 per channel: Ke stays the mean)

  bool emissive() const { return !is_black(ke); }
  /// The radiance Ke leaving a surface of this material along a direction on the side of `side` (a
  /// sign: dot(front normal, direction), the normal by the right-hand rule on the corner order).
  Vec3 emitted(float side) const { return emits_front_only && !(side > 0) ? Vec3(0.f) : ke; }
  bool cut_out() const { return alpha_texture >= 0; }
  bool diffuse() const { return type == MaterialType::kDiffuse; }
};

/// A linear-RGB float image sampled with wrapping texture coordinates: colour bilinear (Blender's
/// "Linear") unless `nearest`, alpha masks nearest texel.
struct Texture {
  std::string path;  // as named in the MTL file, for messages
  int width = 0, height = 0;
  bool nearest = false;      // colour lookups take the nearest texel (a glTF sampler's NEAREST)
  std::vector<float> rgb;    // width * height * 3, row 0 is the top (v = 1); empty if only a mask
  std::vector<float> alpha;  // width * height, the same layout; empty unless a material's mask
  bool header_only = false;  // only its header was read (LoadOptions::decode_textures): no texels to render

  /// The texel (nearest, wrapping) uv falls in, as an index into the width x height texels.
  size_t texel(Vec2 uv) const;
  /// The colour at uv: bilinear between the four nearest texel centres (wrapping), or the nearest texel.
  Vec3 lookup(Vec2 uv) const;
  float alpha_at(Vec2 uv) const { return alpha[texel(uv)]; }
};

/// A tangent-space basis vector at a triangle corner: the tangent (along +u) and the handedness w
/// (+1 or -1) of the bitangent w * cross(normal, t) (along +v), as glTF's TANGENT.
struct Tangent {
  Vec3 t{0.f};
  float w = 1.f;
};

struct Scene {
  std::string name;                                // file name or builtin:NAME
  std::vector<Vec3> positions;                     // world space, metres
  std::vector<std::array<uint32_t, 3>> triangles;  // indices into positions
  std::vector<uint32_t> material_of;               // per triangle, index into materials
  std::vector<std::array<Vec2, 3>> uvs;            // per triangle corner; empty if untextured
  std::vector<std::array<Vec3, 3>> normals;        // per triangle corner, unit shading normals; empty: flat
  std::vector<std::array<Tangent, 3>> tangents;    // per triangle corner; empty unless a normal map is used
  std::vector<Material> materials;
  std::vector<Texture> textures;
  CameraSpec camera;
  Lighting lighting;   // environment and sun (a scene JSON's, or a job's, common/lighting.h)
  std::string folder;  // canonical folder the scene's files are read from; empty for built-ins
  /// Point, spot and directional lights (common/lights.h).
  std::vector<PunctualLight> lights;

  size_t triangle_count() const { return triangles.size(); }
  Bounds3 bounds() const;
  /// Checks indices, finite coordinates and materials; throws std::runtime_error with the reason.
  void validate() const;
  Vec3 geometric_normal(size_t tri) const;
  /// True if some material is a cut-out and some triangle uses it.
  bool has_cut_outs() const;
  /// True if the point of triangle `tri` at barycentrics (u, v) of corners 1 and 2 lies in a hole of
  /// its material's cut-out (false for other materials). The tracer's filters and the master's deep
  /// framebuffer both ask this.
  bool cut_out_at(size_t tri, float u, float v) const;  // unit length, right-hand rule on the corner order
  float area(size_t tri) const;
};

/// Appends a triangle with material `mat` (and corner uvs if the scene is textured).
void add_triangle(Scene& s, Vec3 a, Vec3 b, Vec3 c, uint32_t mat);
/// Appends the quad a-b-c-d (counter-clockwise seen from the front) as two triangles.
void add_quad(Scene& s, Vec3 a, Vec3 b, Vec3 c, Vec3 d, uint32_t mat);
/// Appends a quad split into n x n cells (2 n^2 triangles): the tessellation knob of built-ins.
void add_tessellated_quad(Scene& s, Vec3 a, Vec3 b, Vec3 c, Vec3 d, uint32_t mat, int n);
uint32_t add_material(Scene& s, Material m);
/// Gives the last `count` triangles flat shading normals (and no tangents) if the scene keeps either
/// list, so that the lists stay one entry per triangle.
void append_flat_shading(Scene& s, size_t count);

}  // namespace epr
