// libFuzzer target: the scene loader (common/scene_loader.h) on hostile OBJ, MTL and scene JSON text.
//
// Input: the OBJ text, then optionally a line "#@mtl" followed by the MTL text, then optionally a line
// "#@json" followed by a scene JSON, then optionally a line "#@gltf" followed by a glTF JSON ("#"
// starts an OBJ comment, so a seed stays a readable OBJ):
//
//     v 0 0 0 ...          -> scene/a.obj
//     #@mtl
//     newmtl red ...       -> scene/a.mtl
//     #@json
//     {"obj": "a.obj"}     -> scene/scene.json; loaded instead of a.obj when present
//     #@gltf
//     {"asset": ...}       -> scene/a.gltf; loaded instead of a.obj when there is no scene JSON
//
// The folder also holds fixed files the mutated text can name: buf.bin (a glTF buffer: one triangle's
// three float positions, then indices 0 1 2 as uint16), tex.png (a valid 2x2 texture), bad.png
// (a corrupt one), empty.png, a FIFO, a symlink loop, a folder, symlinks that leave the folder and,
// outside it, marker files (outside.mtl, outside.png, outside.obj, outside.bin).
//
// What must hold: load_scene returns a valid scene or throws SceneError whose message starts with the
// path of a file of the scene (the file it names); nothing else is thrown, nothing outside the scene
// folder is read (the markers never show up in a loaded scene), the sanitizers stay quiet, and limits
// keep time and memory bounded.
#include <OpenImageIO/imageio.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>

#include "common/image.h"
#include "common/log.h"
#include "common/scene_loader.h"

namespace {

namespace fs = std::filesystem;
using namespace epr;

// Markers of the files outside the scene folder: seeing one in a loaded scene means the loader
// followed a path out of the folder.
constexpr const char* kOutsideMaterial = "ESCAPED_MARKER";
constexpr float kOutsideCoordinate = 12345.f;
constexpr int kOutsideTextureWidth = 3, kOutsideTextureHeight = 5;

struct Folder {
  fs::path root;   // holds the outside markers
  fs::path scene;  // root/scene: what the loader may read
};

void write(const fs::path& p, std::string_view text) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out.write(text.data(), std::streamsize(text.size()));
  if (!out) {
    std::fprintf(stderr, "cannot write %s\n", p.c_str());
    std::abort();
  }
}

Image solid(int w, int h, Vec3 c) {
  Image img(w, h, 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) img.set_rgb(x, y, c);
  return img;
}

const Folder& folder() {
  static const Folder f = [] {
    const fs::path base = fs::exists("/dev/shm") ? fs::path("/dev/shm") : fs::temp_directory_path();
    // libFuzzer often leaves through _Exit (atexit handlers do not run): remove the folders of
    // earlier runs whose process is gone.
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(base, ec)) {
      const std::string name = entry.path().filename().string();
      if (name.rfind("epr_scene_fuzz_", 0) != 0) continue;
      const long pid = std::strtol(name.c_str() + 15, nullptr, 10);
      if (pid > 0 && ::kill(pid_t(pid), 0) != 0 && errno == ESRCH) fs::remove_all(entry.path(), ec);
    }
    Folder d;
    d.root = base / ("epr_scene_fuzz_" + std::to_string(::getpid()));
    d.scene = d.root / "scene";
    fs::remove_all(d.root);
    fs::create_directories(d.scene / "sub");
    write(d.root / "outside.mtl", std::string("newmtl ") + kOutsideMaterial + "\nKd 0.1 0.2 0.3\n");
    write(d.root / "outside.obj", "v 12345 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n");
    const float tri[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0}, out_tri[9] = {kOutsideCoordinate, 0, 0, 1, 0, 0, 0, 1, 0};
    const uint16_t idx[3] = {0, 1, 2};
    write(d.scene / "buf.bin",
          std::string(reinterpret_cast<const char*>(tri), 36) + std::string(reinterpret_cast<const char*>(idx), 6));
    write(d.root / "outside.bin",
          std::string(reinterpret_cast<const char*>(out_tri), 36) + std::string(reinterpret_cast<const char*>(idx), 6));
    write_png_srgb((d.root / "outside.png").string(), solid(kOutsideTextureWidth, kOutsideTextureHeight, {1, 0, 0}));
    write_png_srgb((d.scene / "tex.png").string(), solid(2, 2, {0.5f, 0.25f, 1}));
    write(d.scene / "bad.png", std::string("\x89PNG\r\n\x1a\n\0\0\0\rIHDR\0\0\x10\0\0\0\x10\0garbage", 32));
    write(d.scene / "empty.png", "");
    write(d.scene / "sub" / "b.mtl", "newmtl sub\nKd 0.5 0.5 0.5\nmap_Kd ../tex.png\n");
    ::mkfifo((d.scene / "fifo.mtl").c_str(), 0600);
    fs::create_symlink("loop.mtl", d.scene / "loop.mtl");
    fs::create_symlink("../outside.mtl", d.scene / "link_out.mtl");
    fs::create_symlink("../outside.png", d.scene / "link_out.png");
    fs::create_directory_symlink("..", d.scene / "up");
    std::atexit([] {
      std::error_code ec;
      fs::remove_all(folder().root, ec);
    });
    return d;
  }();
  return f;
}

[[noreturn]] void bug(const std::string& what) {
  std::fprintf(stderr, "scene_loader_fuzz: %s\n", what.c_str());
  std::abort();
}

void check_scene(const Scene& s) {
  s.validate();  // throws (and so fails the run) if the loader returned an inconsistent scene
  for (const Material& m : s.materials)
    if (m.name == kOutsideMaterial) bug("a material from outside the scene folder was loaded");
  for (const Vec3& p : s.positions)
    if (p.x == kOutsideCoordinate) bug("an OBJ from outside the scene folder was loaded");
  for (const Texture& t : s.textures) {
    if (t.width == kOutsideTextureWidth && t.height == kOutsideTextureHeight)
      bug("a texture from outside the scene folder was loaded");
    const size_t texels = size_t(t.width) * size_t(t.height);
    // A texture keeps colour, a mask, or both (a mask-only texture keeps no colour).
    if (t.rgb.empty() && t.alpha.empty()) bug("a texture with neither colour nor mask");
    if (!t.rgb.empty() && t.rgb.size() != texels * 3) bug("texture size does not match its texels");
    if (!t.alpha.empty() && t.alpha.size() != texels) bug("mask size does not match its texels");
    for (float v : t.rgb)
      if (!(v >= 0.f && v <= 1.f)) bug("texel outside [0, 1]");
  }
  for (const auto& tri : s.uvs)
    for (const Vec2& uv : tri)
      if (!std::isfinite(uv.x) || !std::isfinite(uv.y)) bug("non-finite texture coordinate");
  for (size_t t = 0; t < s.triangle_count(); ++t)
    if (!(s.area(t) >= 0.f)) bug("triangle with NaN area");
}

}  // namespace

// OpenImageIO 2.4's PNG reader leaks its error message when libpng longjmps out of a corrupt file
// (PNGInput::PngReadCallback): a leak in the system library, not in the loader.
extern "C" const char* __lsan_default_suppressions() { return "leak:PngReadCallback\nleak:ImageInput::geterror\n"; }

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  set_log_level("off");
  // A texture that its extension's reader refuses would otherwise go through every reader OpenImageIO
  // has (~0.5 s a file here): the decoders are not what this target tests, the loader's handling of
  // their refusal is.
  OIIO::attribute("try_all_readers", 0);
  OIIO::attribute("threads", 1);
  folder();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const Folder& f = folder();
  std::string_view in(reinterpret_cast<const char*>(data), size);
  const size_t gltf_at = in.find("#@gltf\n");
  std::error_code ec;
  fs::remove(f.scene / "a.gltf", ec);
  if (gltf_at != std::string_view::npos) {
    write(f.scene / "a.gltf", in.substr(gltf_at + 7));
    in = in.substr(0, gltf_at);
  }
  const size_t mtl_at = in.find("#@mtl\n");
  const size_t json_at = in.find("#@json\n", mtl_at == std::string_view::npos ? 0 : mtl_at);
  const std::string_view obj = in.substr(0, std::min(mtl_at, json_at));
  std::string_view mtl;
  if (mtl_at != std::string_view::npos)
    mtl = in.substr(mtl_at + 6, json_at == std::string_view::npos ? in.npos : json_at - mtl_at - 6);
  const bool has_json = json_at != std::string_view::npos;

  write(f.scene / "a.obj", obj);
  write(f.scene / "a.mtl", mtl);
  fs::remove(f.scene / "scene.json", ec);
  if (has_json) write(f.scene / "scene.json", in.substr(json_at + 7));

  LoadOptions opts;
  opts.max_triangles = 100'000;  // also bounds the built-in scenes a JSON may ask for
  opts.max_file_bytes = 1 << 20;
  opts.max_texture_pixels = 1 << 16;
  const char* entry = has_json ? "scene.json" : gltf_at != std::string_view::npos ? "a.gltf" : "a.obj";
  const std::string spec = (f.scene / entry).string();
  try {
    check_scene(load_scene(spec, opts));
  } catch (const SceneError& e) {
    // The message names a file of the scene: it starts with the scene folder's path.
    const std::string_view msg = e.what();
    if (msg.rfind(f.scene.string() + "/", 0) != 0)
      bug("SceneError does not start with a scene file: " + std::string(msg));
    if (msg.find(": ") == std::string_view::npos) bug("SceneError without a reason: " + std::string(msg));
  } catch (const std::exception& e) {
    bug(std::string("exception other than SceneError: ") + e.what());
  }
  return 0;
}
