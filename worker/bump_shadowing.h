// The bump shadowing term of Chiang, Li and Burley, "Taming the Shadow Terminator" (SIGGRAPH 2019
// talk), as Cycles 3.x applies it (bump_shadowing_term, kernel/closure/bsdf.h): a diffuse lobe
// whose shading normal ns was tilted away from the surface's smooth (interpolated) normal n, by a
// normal map or by the bend towards the face normal, has its value towards wi multiplied by G(g),
// g = dot(n, wi) / (dot(ns, wi) dot(n, ns)): G = 1 for g >= 1, 0 for g < 0, else -g^3 + g^2 + g
// (a smooth step).
// Light arriving from the side the tilt turned away from keeps its full value; light the tilt turned
// towards loses some, as if the bumps shadowed each other. Cycles' diffuse closures (its Diffuse BSDF
// and the Principled BSDF's diffuse base) take it in evaluation and in sampling alike, their density
// unchanged; eprfarm's diffuse lobes do the same (worker/bsdf.h), so that a normal-mapped surface
// renders as Blender renders it.
#pragma once

#include "common/math.h"

namespace epr {

/// G for the smooth normal n, the shading normal ns and the direction wi (all unit length, n and ns
/// on the same side). 1 where ns == n.
inline float bump_shadowing_term(const Vec3& n, const Vec3& ns, const Vec3& wi) {
  const float denom = dot(ns, wi) * dot(n, ns);
  const float g = denom != 0 ? dot(n, wi) / denom : 0.f;
  if (g >= 1) return 1;
  if (!(g >= 0)) return 0;
  const float g2 = g * g;
  return -g2 * g + g2 + g;
}

}  // namespace epr
