#include "common/scene_loader/gltf_accessor.h"

#include <fmt/format.h>

#include <algorithm>

#include "common/scene_loader/text.h"

namespace epr::loader {

View accessor_view(const tinygltf::Model& m, int a, const std::string& where, const char* role,
                   const std::string& file) {
  if (a < 0 || size_t(a) >= m.accessors.size())
    fail_file(file,
              fmt::format("{}: {} accessor {} does not exist ({} accessors)", where, role, a, m.accessors.size()));
  const tinygltf::Accessor& acc = m.accessors[size_t(a)];
  const std::string aw = fmt::format("{}: {} accessors[{}]", where, role, a);
  if (acc.sparse.isSparse) fail_file(file, aw + " is sparse, which is not supported");
  if (acc.bufferView < 0 || size_t(acc.bufferView) >= m.bufferViews.size())
    fail_file(file, fmt::format("{} has no bufferView (bufferView {})", aw, acc.bufferView));
  const tinygltf::BufferView& bv = m.bufferViews[size_t(acc.bufferView)];
  if (bv.buffer < 0 || size_t(bv.buffer) >= m.buffers.size())
    fail_file(file,
              fmt::format("{}: bufferViews[{}] names buffer {}, which does not exist", aw, acc.bufferView, bv.buffer));
  const std::vector<unsigned char>& data = m.buffers[size_t(bv.buffer)].data;
  if (bv.byteOffset > data.size() || bv.byteLength > data.size() - bv.byteOffset)
    fail_file(file, fmt::format("{}: bufferViews[{}] (bytes {}..{}) lies outside buffers[{}] ({} bytes)", aw,
                                acc.bufferView, bv.byteOffset, bv.byteOffset + bv.byteLength, bv.buffer, data.size()));
  const int csize = tinygltf::GetComponentSizeInBytes(uint32_t(acc.componentType));
  const int ncomp = tinygltf::GetNumComponentsInType(uint32_t(acc.type));
  if (csize <= 0 || ncomp <= 0) fail_file(file, aw + " has an unknown component type or type");
  const size_t elem = size_t(csize) * size_t(ncomp);
  const size_t stride = bv.byteStride > 0 ? bv.byteStride : elem;
  if (stride < elem)
    fail_file(file, fmt::format("{}: byteStride {} is less than an element ({} bytes)", aw, stride, elem));
  View v{data.data() + bv.byteOffset + std::min(acc.byteOffset, bv.byteLength), acc.count, stride, acc.componentType,
         acc.normalized};
  if (acc.count > 0 && (acc.byteOffset > bv.byteLength || acc.count - 1 > (bv.byteLength - acc.byteOffset) / stride ||
                        (acc.count - 1) * stride + elem > bv.byteLength - acc.byteOffset))
    fail_file(file,
              fmt::format("{} is out of range: {} elements of {} bytes from byte {} do not fit in bufferViews[{}] ({} "
                          "bytes)",
                          aw, acc.count, elem, acc.byteOffset, acc.bufferView, bv.byteLength));
  return v;
}

}  // namespace epr::loader
