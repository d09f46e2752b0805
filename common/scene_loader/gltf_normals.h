// glTF NORMAL and TANGENT vertex attributes (scenes/README.md, "glTF 2.0"): checked and placed in the
// world by a node's transform, normals by its inverse transpose. gltf.cpp reads the accessors.
#pragma once

#include <array>
#include <string>
#include <vector>

#include "common/scene.h"
#include "common/scene_loader/gltf_files.h"

namespace epr::loader {

/// The raw elements of a NORMAL (x, y, z, unused) or TANGENT (x, y, z, w) accessor.
using RawVectors = std::vector<std::array<double, 4>>;

/// NORMAL elements placed by the column-major transform `world`: multiplied by its 3x3 part's
/// inverse transpose (the cofactor matrix with the determinant's sign, defined for singular
/// transforms too) and normalised; a zero vector where the transform flattens the normal away (the
/// loader then uses the triangle's own). An element that is not finite or is zero raises
/// SceneError "file: `what` element i (x, y, z) is not finite / has zero length".
std::vector<Vec3> world_normals(const RawVectors& raw, const std::array<double, 16>& world, const std::string& file,
                                const std::string& what);

/// TANGENT elements: xyz placed by `world`'s 3x3 part, w the handedness (its sign, negated by a
/// mirroring transform). Checked as world_normals() does (xyz non-zero, w finite and non-zero).
std::vector<Tangent> world_tangents(const RawVectors& raw, const std::array<double, 16>& world, const std::string& file,
                                    const std::string& what);

/// Primitive `prim`'s (in `where`) NORMAL, or TANGENT, of its `count` vertices placed by `world`
/// as above; empty if it has none. The accessor must be float VEC3 (VEC4) with `count` elements.
std::vector<Vec3> read_normals(const tinygltf::Model& m, const tinygltf::Primitive& prim, const std::string& where,
                               size_t count, const std::array<double, 16>& world, const std::string& file);
std::vector<Tangent> read_tangents(const tinygltf::Model& m, const tinygltf::Primitive& prim, const std::string& where,
                                   size_t count, const std::array<double, 16>& world, const std::string& file);

}  // namespace epr::loader
