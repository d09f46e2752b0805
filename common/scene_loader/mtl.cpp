// MTL material libraries: each file validated line by line (messages name file and line), its
// textures loaded, and its materials added to the OBJ's material table.
//
// The material model uses newmtl, Kd, Ke, Ks, Ns, map_Kd and map_d (an alpha mask: the material is
// cut out where the texture's alpha, or the first channel of an image without alpha, is below 0.5),
// and eprfarm's own `emit front` (Ke leaves the faces' front side only; `emit both` is the default);
// other statements (Ka, Ni, d, illum, other maps...) are ignored. The files named by one mtllib statement are read as
// one library, in the way of tinyobjloader's MTL reader, so that material tables match that library's:
//   - a material is added when the next newmtl starts, and once more at the end of the library
//     (an unnamed black one if the library defines none);
//   - a map_Kd sets kd to 0.6 unless a Kd came earlier in the library (in any material).
#include <fmt/format.h>
#include <tiny_obj_loader.h>

#include <algorithm>
#include <set>
#include <string>
#include <vector>

#include "common/scene_loader/obj_context.h"
#include "common/scene_loader/text.h"

namespace epr::loader {
namespace {

namespace fs = std::filesystem;

/// Validates an MTL file and loads its textures.
MtlFile read_mtl(ObjContext& ctx, const FileRef& mtl) {
  const std::string text = read_file(mtl, ctx.opts.max_file_bytes, &ctx.report);
  const fs::path dir = mtl.real.parent_path();
  const std::string display_dir = fs::path(mtl.display).parent_path().string();
  const std::string& file = mtl.display;

  MtlFile out;
  out.bytes = text.size();
  StatementReader statements(text, file);
  std::string current;  // material being defined
  std::set<std::string> names_here;
  while (statements.next()) {
    const size_t ln = statements.line_number();
    const std::string_view line = statements.line();
    const std::vector<std::string_view>& tok = statements.tokens();
    const std::string_view key = tok[0];
    MtlStatement st;
    if (key == "newmtl") {
      if (tok.size() < 2) fail(file, ln, "newmtl without a material name");
      current = std::string(tok[1]);
      if (!names_here.insert(current).second || ctx.defined_materials.count(current))
        warn(ctx.report,
             fmt::format("{}:{}: material '{}' is defined again; the first definition is used", file, ln, current));
      st.kind = MtlStatement::Kind::kNewmtl;
      st.name = current;
    } else if (key == "Kd" || key == "Ke" || key == "Ks") {
      if (current.empty()) fail(file, ln, fmt::format("{} before any newmtl", key));
      if (tok.size() != 2 && tok.size() != 4)
        fail(file, ln,
             fmt::format("{} needs 1 or 3 numbers (spectral and xyz forms are not supported), got {}", key,
                         tok.size() - 1));
      for (int k = 0; k < 3; ++k)  // one number means grey
        st.value[k] = parse_real(tok[std::min(size_t(k) + 1, tok.size() - 1)], 1e6, file, ln, "colour value");
      st.kind =
          key == "Kd" ? MtlStatement::Kind::kKd : (key == "Ke" ? MtlStatement::Kind::kKe : MtlStatement::Kind::kKs);
    } else if (key == "Ns") {
      if (current.empty()) fail(file, ln, "Ns before any newmtl");
      if (tok.size() != 2) fail(file, ln, fmt::format("Ns needs 1 number, got {}", tok.size() - 1));
      st.kind = MtlStatement::Kind::kNs;
      st.value.x = parse_real(tok[1], 1e6, file, ln, "Ns exponent");
    } else if (key == "emit") {
      if (current.empty()) fail(file, ln, "emit before any newmtl");
      if (tok.size() != 2 || (tok[1] != "front" && tok[1] != "both"))
        fail(file, ln, "emit needs one word: front (Ke leaves the front side only) or both (the default)");
      st.kind = MtlStatement::Kind::kEmit;
      st.value.x = tok[1] == "front" ? 1.f : 2.f;
    } else if (key == "map_Kd" || key == "map_d") {
      if (current.empty()) fail(file, ln, fmt::format("{} before any newmtl", key));
      // The texture options (-s, -o, -clamp...) are parsed to find the file name, and not used.
      const std::string args(rest_after_keyword(line, key));
      std::string texname;
      tinyobj::texture_option_t opt{};
      if (!tinyobj::ParseTextureNameAndOption(&texname, &opt, args.c_str()) || strip_comment(texname).empty())
        fail(file, ln, fmt::format("{} of material '{}' without a texture file name", key, current));
      texname = std::string(strip_comment(texname));
      const bool mask = key == "map_d";
      st.kind = mask ? MtlStatement::Kind::kMapD : MtlStatement::Kind::kMapKd;
      st.texture =
          load_texture(ctx, texname, dir, display_dir, file, ln, mask ? TextureUse::kMask : TextureUse::kColour);
    } else {
      continue;  // not part of the material model
    }
    out.statements.push_back(std::move(st));
  }
  ctx.defined_materials.insert(names_here.begin(), names_here.end());
  return out;
}

/// Appends the materials of the library made of `files` to `table`.
void add_library(const std::vector<const MtlFile*>& files, MaterialTable* table) {
  auto add = [&](const MtlMaterial& m) {
    table->first_of_name.emplace(m.name, int(table->materials.size()));
    table->materials.push_back(m);
  };
  MtlMaterial current;
  bool has_kd = false;
  for (const MtlFile* f : files)
    for (const MtlStatement& st : f->statements) switch (st.kind) {
        case MtlStatement::Kind::kNewmtl:
          if (!current.name.empty()) add(current);
          current = MtlMaterial{};
          current.name = st.name;
          break;
        case MtlStatement::Kind::kKd:
          current.kd = st.value;
          has_kd = true;
          break;
        case MtlStatement::Kind::kKe:
          current.ke = st.value;
          break;
        case MtlStatement::Kind::kKs:
          current.ks = st.value;
          break;
        case MtlStatement::Kind::kNs:
          current.ns = st.value.x;
          break;
        case MtlStatement::Kind::kMapKd:
          current.texture = st.texture;
          if (!has_kd) current.kd = Vec3(0.6f);
          break;
        case MtlStatement::Kind::kMapD:
          current.mask = st.texture;
          break;
        case MtlStatement::Kind::kEmit:
          current.emit_front_only = st.value.x == 1.f;
          break;
      }
  add(current);
}

}  // namespace

void apply_mtllib(ObjContext& ctx, const std::vector<FileRef>& mtls, const std::string& file, size_t line) {
  std::vector<fs::path> reals;
  for (const FileRef& mtl : mtls) reals.push_back(mtl.real);
  if (ctx.mtl_lists.count(reals)) return;  // the same list again: its materials are in the table
  std::vector<const MtlFile*> files;
  size_t bytes = 0;
  for (const FileRef& mtl : mtls) {
    auto it = ctx.mtl_files.find(mtl.real);
    if (it == ctx.mtl_files.end()) it = ctx.mtl_files.emplace(mtl.real, read_mtl(ctx, mtl)).first;
    files.push_back(&it->second);
    bytes += it->second.bytes;
  }
  // Each new list adds all of its files' materials again: the total is bounded like one file.
  ctx.mtl_bytes += bytes;
  if (ctx.mtl_bytes > ctx.opts.max_file_bytes)
    fail(file, line, fmt::format("material libraries exceed {} bytes in total", ctx.opts.max_file_bytes));
  ctx.mtl_lists.insert(std::move(reals));
  add_library(files, &ctx.table);
}

}  // namespace epr::loader
