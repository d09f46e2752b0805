// Shading normals: the normal a surface is shaded with (its BSDF's frame and cosine), which smooth
// shading and normal maps make differ from the geometric normal that ray offsets, side tests and
// reprojection use. The path tracer (worker/path_tracer.cpp) asks for them at every hit.
#pragma once

#include "common/math.h"
#include "common/scene.h"

namespace epr {

/// The interpolated corner normal of triangle `tri` at barycentrics (u, v) of corners 1 and 2 (the
/// geometric normal if the scene has no normals or they cancel), unit length, on the side the scene
/// gives it (not yet turned towards a viewer).
Vec3 interpolated_normal(const Scene& s, size_t tri, float u, float v);

/// interpolated_normal() perturbed by the triangle's material's normal map, if it has one.
Vec3 shading_normal(const Scene& s, size_t tri, float u, float v);

/// The shading normal n (from shading_normal()) as a BSDF at a hit uses it, seen from direction wo
/// (unit, away from the surface) with ng the unit geometric normal already turned towards wo: n turned
/// to ng's side, then bent towards ng as Cycles does (ensure_valid_specular_reflection,
/// kernel/closure/bsdf_util.h) so that wo's mirror image about it lies above the geometric surface
/// by min(0.9 dot(wo, ng), 0.01): wo is then never below the shading hemisphere. Unit length.
Vec3 oriented_shading_normal(Vec3 n, Vec3 ng, Vec3 wo);

/// What a hit on triangle `tri` at (u, v) shades with, seen from wo with the oriented geometric
/// normal ng: oriented_shading_normal(shading_normal(...), ng, wo), or ng itself (bit for bit, so
/// that flat scenes render as they did) where the triangle has neither corner normals nor a normal map.
Vec3 shading_normal_towards(const Scene& s, size_t tri, float u, float v, Vec3 ng, Vec3 wo);

/// The two normals a BSDF at a hit takes (worker/bsdf.h): `shading` as shading_normal_towards()
/// gives it, and `smooth`, the interpolated normal (before the normal map and the bend) turned to
/// ng's side, which the diffuse lobes' bump shadowing term compares it with. Both ng (bit for bit)
/// where the triangle has neither corner normals nor a normal map.
struct HitNormals {
  Vec3 smooth, shading;
};
HitNormals hit_normals_towards(const Scene& s, size_t tri, float u, float v, Vec3 ng, Vec3 wo);

}  // namespace epr
