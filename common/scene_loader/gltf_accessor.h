// glTF accessors as the loader reads them: an accessor's elements in their buffer, bounds checked
// once (gltf.cpp's positions, uvs and indices, gltf_normals.cpp's normals and tangents).
#pragma once

#include <cstddef>
#include <cstring>
#include <string>

#include "common/scene_loader/gltf_files.h"

namespace epr::loader {

/// An accessor's elements in their buffer, bounds checked.
struct View {
  const unsigned char* base = nullptr;
  size_t count = 0, stride = 0;
  int component = 0;  // TINYGLTF_COMPONENT_TYPE_*
  bool normalized = false;

  double get(size_t i, size_t k) const {
    const unsigned char* p = base + i * stride;
    switch (component) {
      case TINYGLTF_COMPONENT_TYPE_FLOAT: {
        float f;
        std::memcpy(&f, p + 4 * k, 4);
        return f;
      }
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
        return p[k] / (normalized ? 255.0 : 1.0);
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: {
        uint16_t v;
        std::memcpy(&v, p + 2 * k, 2);
        return v / (normalized ? 65535.0 : 1.0);
      }
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT: {
        uint32_t v;
        std::memcpy(&v, p + 4 * k, 4);
        return v;
      }
      default:
        return 0;
    }
  }
};

/// The elements of accessor `a` (its `role` in `where`, for messages); raises SceneError naming
/// `file` and the accessor if it is missing, sparse or does not fit in its buffer.
View accessor_view(const tinygltf::Model& m, int a, const std::string& where, const char* role,
                   const std::string& file);

}  // namespace epr::loader
