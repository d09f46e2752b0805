// A lit OBJ scene of a given size for the tests of large uploads: a floor grid of triangles under an
// emissive material (an unlit scene is refused), with its MTL beside it.
#pragma once

#include <fmt/format.h>

#include <filesystem>
#include <fstream>
#include <string>

namespace epr::test {

/// Writes DIR/large.obj (at least `min_bytes` long) and DIR/large.mtl; returns the OBJ's path.
inline std::string write_large_obj(const std::filesystem::path& dir, size_t min_bytes) {
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "large.mtl") << "newmtl glow\nKd 0.5 0.5 0.5\nKe 1 1 1\n";
  std::ofstream obj(dir / "large.obj");
  obj << "mtllib large.mtl\nusemtl glow\n";
  size_t written = 0;
  for (int row = 0; written < min_bytes; ++row) {
    // One strip of 64 quads per row: 130 vertices, 128 triangles, indices relative to the row.
    std::string strip;
    for (int i = 0; i <= 64; ++i)
      strip += fmt::format("v {:.6f} 0.000000 {:.6f}\nv {:.6f} 0.000000 {:.6f}\n", i / 64.0 - 0.5, row * 0.001 - 0.5,
                           i / 64.0 - 0.5, row * 0.001 - 0.499);
    for (int i = 0; i < 64; ++i) {
      const int v = 2 * i - 130;  // negative: counted back from the row's last vertex
      strip += fmt::format("f {} {} {}\nf {} {} {}\n", v, v + 2, v + 1, v + 1, v + 2, v + 3);
    }
    obj << strip;
    written += strip.size();
  }
  return (dir / "large.obj").string();
}

}  // namespace epr::test
