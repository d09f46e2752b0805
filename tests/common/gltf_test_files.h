// Writing small glTF 2.0 files for the loader tests: a builder of buffers, accessors and meshes
// that writes a .gltf with its .bin, or a .glb.
#pragma once

#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "tests/common/scene_test_files.h"

namespace epr::test {

template <typename T>
std::string bytes_of(const std::vector<T>& v) {
  std::string s(v.size() * sizeof(T), '\0');
  if (!v.empty()) std::memcpy(s.data(), v.data(), s.size());
  return s;
}

class GltfBuilder {
 public:
  GltfBuilder() {
    doc["asset"] = {{"version", "2.0"}};
    doc["scene"] = 0;
    doc["scenes"] = nlohmann::json::array({{{"nodes", nlohmann::json::array()}}});
    doc["nodes"] = nlohmann::json::array();
    doc["meshes"] = nlohmann::json::array();
    doc["accessors"] = nlohmann::json::array();
    doc["bufferViews"] = nlohmann::json::array();
  }

  /// Appends `data` to the binary buffer (4-byte aligned); returns its bufferView.
  int view(const std::string& data) {
    while (bin.size() % 4) bin.push_back('\0');
    doc["bufferViews"].push_back({{"buffer", 0}, {"byteOffset", bin.size()}, {"byteLength", data.size()}});
    bin += data;
    return int(doc["bufferViews"].size() - 1);
  }
  int accessor(const std::string& data, int component, size_t count, const char* type) {
    doc["accessors"].push_back(
        {{"bufferView", view(data)}, {"componentType", component}, {"count", count}, {"type", type}});
    return int(doc["accessors"].size() - 1);
  }
  /// A mesh of one primitive; indices and uvs optional (empty). Returns the mesh index.
  int mesh(const std::vector<float>& xyz, const std::vector<uint16_t>& indices = {}, int material = -1,
           const std::vector<float>& uv = {}, int mode = 4) {
    nlohmann::json prim;
    prim["attributes"]["POSITION"] = accessor(bytes_of(xyz), 5126, xyz.size() / 3, "VEC3");
    if (!uv.empty()) prim["attributes"]["TEXCOORD_0"] = accessor(bytes_of(uv), 5126, uv.size() / 2, "VEC2");
    if (!indices.empty()) prim["indices"] = accessor(bytes_of(indices), 5123, indices.size(), "SCALAR");
    if (material >= 0) prim["material"] = material;
    prim["mode"] = mode;
    doc["meshes"].push_back({{"primitives", nlohmann::json::array({prim})}});
    return int(doc["meshes"].size() - 1);
  }
  /// A node (a root of the scene unless `root` is false); returns its index.
  int node(nlohmann::json n, bool root = true) {
    doc["nodes"].push_back(std::move(n));
    const int i = int(doc["nodes"].size() - 1);
    if (root) doc["scenes"][0]["nodes"].push_back(i);
    return i;
  }
  int material(nlohmann::json m) {
    doc["materials"].push_back(std::move(m));
    return int(doc["materials"].size() - 1);
  }

  /// Writes DIR/NAME.gltf and DIR/NAME.bin; returns the .gltf's path.
  std::string write_gltf(const TempDir& dir, const std::string& name) {
    nlohmann::json d = doc;
    const std::string file = std::filesystem::path(name).filename().string() + ".bin";
    d["buffers"] = nlohmann::json::array({{{"uri", file}, {"byteLength", bin.size()}}});
    dir.write(name + ".bin", bin);
    return dir.write(name + ".gltf", d.dump(1));
  }
  /// Writes DIR/NAME.glb (JSON and binary chunks in one file); returns its path.
  std::string write_glb(const TempDir& dir, const std::string& name) {
    nlohmann::json d = doc;
    std::string b = bin;
    while (b.size() % 4) b.push_back('\0');
    d["buffers"] = nlohmann::json::array({{{"byteLength", b.size()}}});
    std::string json = d.dump();
    while (json.size() % 4) json.push_back(' ');
    std::string out = "glTF";
    auto u32 = [&](uint32_t v) { out.append(reinterpret_cast<const char*>(&v), 4); };
    u32(2);
    u32(uint32_t(12 + 8 + json.size() + 8 + b.size()));
    u32(uint32_t(json.size()));
    u32(0x4E4F534Au);
    out += json;
    u32(uint32_t(b.size()));
    u32(0x004E4942u);
    out += b;
    return dir.write(name + ".glb", out);
  }

  nlohmann::json doc;
  std::string bin;
};

/// An 8-bit RGB PNG written as stored (no transfer curve): data such as a normal map.
inline void write_rgb8_png(const std::string& path, int w, int h, const std::vector<float>& rgb) {
  auto out = OIIO::ImageOutput::create(path);
  ASSERT_TRUE(out);
  OIIO::ImageSpec spec(w, h, 3, OIIO::TypeDesc::UINT8);
  ASSERT_TRUE(out->open(path, spec));
  ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, rgb.data()));
  out->close();
}

}  // namespace epr::test
