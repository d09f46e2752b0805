// Tangent space for normal maps (glTF normalTexture): tangents from the uv layout where a scene gives
// none, approximating MikkTSpace (glTF's rule), and a normal map's texel turned into a normal.
//
// Conventions: uv as the scene stores it (v up, Blender's and OpenGL's), the tangent along +u and
// the bitangent w * cross(n, t) along +v; a normal map's green channel points along +v ("OpenGL"
// normal maps, as glTF and Blender define them).
#pragma once

#include <array>
#include <vector>

#include "common/math.h"
#include "common/scene.h"

namespace epr {

/// The directions of +u and +v on the triangle p (from the uv derivatives), scaled alike by the
/// inverse of the uv area; both zero if the triangle's uv area is zero.
struct UvDerivatives {
  Vec3 dp_du{0.f}, dp_dv{0.f};
};
UvDerivatives uv_derivatives(const std::array<Vec3, 3>& p, const std::array<Vec2, 3>& uv);

/// Fills scene.tangents (made one entry per triangle, new entries zero) for the triangles with
/// needed[i] true, leaving the others as they are, from scene.positions, scene.uvs and scene.normals (the geometric
/// normal where the scene has none). As MikkTSpace does: corners with the same position, normal and
/// uv are one vertex; each triangle adds its dP/du and dP/dv, projected onto the corner normal's
/// plane, normalised and weighted by the corner's angle, to its vertices, apart for each handedness
/// (a mirrored uv island keeps its own tangents); the sum is orthogonalised against the normal
/// (Gram-Schmidt), its handedness the sign of the summed bitangent against cross(n, t). Unlike
/// MikkTSpace, vertices are not split where the tangents of a smooth group diverge sharply, and a
/// triangle whose uv area is zero gets its vertices' tangents from its neighbours only.
void generate_tangents(Scene& scene, const std::vector<bool>& needed);

/// The normal a tangent-space normal map's texel (as stored: [0, 1] per channel, 0.5 is 0) gives at
/// a point of unit shading normal n and tangent t: normalize(x T + y B + z n), with x and y (the
/// map's red and green, 2 c - 1) multiplied by `scale`, T = t orthogonalised against n and
/// B = t.w cross(n, T). n itself where t is unusable (zero or along n).
Vec3 apply_normal_map(Vec3 n, const Tangent& t, Vec3 texel, float scale);

}  // namespace epr
