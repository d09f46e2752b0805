// What the OBJ reader (obj.cpp), the MTL reader (mtl.cpp) and the texture reader (textures.cpp)
// share while one OBJ is loaded: the limits, the scene folder, the textures read so far and the
// table of materials the OBJ's mtllib statements have defined.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <map>
#include <set>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "common/scene.h"
#include "common/scene_error.h"
#include "common/scene_loader/path_sandbox.h"

namespace epr::loader {

/// A material as its MTL file defines it, before the loader clamps it into a Material. Values not
/// given keep these defaults (as in tinyobjloader: black, Ns 1).
struct MtlMaterial {
  std::string name;
  Vec3 kd{0.f}, ke{0.f}, ks{0.f};
  float ns = 1.f;
  int texture = -1;              // map_Kd: index into ObjContext::textures
  int mask = -1;                 // map_d: index into ObjContext::textures (its alpha)
  bool emit_front_only = false;  // emit front
};

/// One statement of an MTL file that the material model uses.
struct MtlStatement {
  enum class Kind : uint8_t { kNewmtl, kKd, kKe, kKs, kNs, kMapKd, kMapD, kEmit };
  Kind kind = Kind::kNewmtl;
  Vec3 value{0.f};   // Kd, Ke, Ks: the colour; Ns: value.x; emit: value.x 1 (front) or 2 (both)
  int texture = -1;  // map_Kd, map_d
  std::string name;  // newmtl
};

/// An MTL file, validated: its statements in file order.
struct MtlFile {
  std::vector<MtlStatement> statements;
  size_t bytes = 0;  // size of the file
};

/// The materials an OBJ's mtllib statements define, in order. A name defined twice appears twice;
/// usemtl finds the first.
struct MaterialTable {
  std::vector<MtlMaterial> materials;
  std::unordered_map<std::string, int> first_of_name;
};

/// What a texture file is read for: its colour (Texture::rgb), or its alpha as a cut-out mask
/// (Texture::alpha): the alpha channel, or where the image has none its first channel (kMask: MTL
/// map_d, which may name a grey image) or full opacity (kAlpha: glTF base colour), or its RGB as
/// stored, not sRGB-decoded (kData: a normal map; a Texture of its own, not shared with the others).
enum class TextureUse : uint8_t { kColour, kMask, kAlpha, kData };

/// What a texture's uses need decoded (load_texture notes it; decode_textures or texels() decodes it),
/// and the reference that named it first, for messages.
struct PendingTexels {
  FileRef ref;
  std::string name, file;  // the texture as named, the file (and line) naming it
  size_t line = 0;
  bool colour = false;                    // Texture::rgb, sRGB-decoded
  bool data = false;                      // Texture::rgb as stored (a normal map)
  TextureUse mask = TextureUse::kColour;  // kMask or kAlpha: Texture::alpha read so; kColour: no mask
  bool done = false;                      // decoded as asked
};

struct ObjContext {
  ObjContext(const LoadOptions& o, std::filesystem::path r, LoadReport& rep)
      : opts(o), root(std::move(r)), report(rep) {}

  const LoadOptions& opts;
  std::filesystem::path root;  // canonical: nothing outside it is read
  LoadReport& report;          // the files read and the warnings
  std::vector<Texture> textures;
  std::map<std::filesystem::path, int> texture_of_path;
  std::map<int, PendingTexels> pending;                    // by index into textures: the files load_texture read
  size_t texture_pixels = 0;                               // total of all textures
  std::map<std::filesystem::path, MtlFile> mtl_files;      // each MTL file read once
  std::set<std::vector<std::filesystem::path>> mtl_lists;  // the mtllib file lists already applied
  size_t mtl_bytes = 0;                                    // total of the applied lists' file sizes
  std::set<std::string> defined_materials;                 // names from the MTL files read so far
  MaterialTable table;
};

/// Adds the texture `name` (from map_Kd or map_d in `file` at `line`, relative to `dir`), one Texture
/// per file: checks the file and its header (size, channels, the scene's pixel limit) and notes what
/// this use needs decoded; returns its index in ctx.textures. Its texels come with decode_textures.
int load_texture(ObjContext& ctx, const std::string& name, const std::filesystem::path& dir,
                 const std::string& display_dir, const std::string& file, size_t line,
                 TextureUse use = TextureUse::kColour);

/// Texture `index` with its texels decoded as its uses so far ask (now, if load_texture left them),
/// for a load that reads them (a colour factor's copy, an emission's mean).
const Texture& texels(ObjContext& ctx, int index);

/// Decodes the texels every load_texture left, in parallel, at the end of a load; errors and warnings
/// as a decode in the textures' order gives them. With LoadOptions::decode_textures false, marks
/// those textures header_only instead.
void decode_textures(ObjContext& ctx);

/// The mtllib statement at `file`:`line` naming `mtls`: reads and validates the files (each once per
/// OBJ, with their textures) and, the first time the OBJ names this list of files, appends their
/// materials to ctx.table, the files of the list read as one library (mtl.cpp describes how).
void apply_mtllib(ObjContext& ctx, const std::vector<FileRef>& mtls, const std::string& file, size_t line);

}  // namespace epr::loader
