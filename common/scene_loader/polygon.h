// Triangulation of OBJ faces. The rules are tinyobjloader's (2.0.0rc10, float build), so an OBJ
// gives the triangles, in the corner order, that OBJ tools built on that library see, and the
// built-in Cornell box matches its OBJ triangle for triangle:
//   - a quad is split along its shorter diagonal: (0 1 2)(0 2 3) if |p2 - p0| < |p3 - p1|, else
//     (0 1 3)(1 2 3);
//   - a larger polygon is ear-clipped in the plane of two coordinate axes, chosen at the first
//     corner that is not collinear (the axes that drop the largest component of its normal). A
//     polygon that has no ear left (self-intersecting or folded) keeps the triangles found so far.
// All arithmetic is in float, in the library's order of operations.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "common/math.h"

namespace epr::loader {

/// Triangulates the face whose k-th corner is positions[vertex[k]] (k < n, n >= 3) and appends its
/// triangles to `out`, each as three corner numbers k (not vertex indices).
void triangulate_face(const std::vector<Vec3>& positions, const uint32_t* vertex, size_t n,
                      std::vector<std::array<uint32_t, 3>>* out);

}  // namespace epr::loader
