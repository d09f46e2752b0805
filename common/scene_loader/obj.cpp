// Wavefront OBJ, read in one pass: each line is tokenised once, validated where it stands (a
// problem raises SceneError naming file and line) and turned into the mesh from the same tokens.
//   - v / vt: finite numbers only (v: x y z [w] [r g b], vt: u [v [w]]), magnitudes bounded;
//   - f: corners "v", "v/vt", "v//vn" or "v/vt/vn" with absolute or relative indices, each checked
//     against what is defined so far; polygons are triangulated as polygon.h describes;
//   - mtllib / usemtl: material libraries (mtl.cpp) and the material of the faces that follow;
//   - vn: finite, non-zero; faces whose corners name them are smooth-shaded with them (normalised;
//     corners without one take the face's normal); g, o, s, l, p and vp are ignored, other
//     statements are ignored with a warning.
#include "common/scene_loader/obj.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <limits>
#include <optional>
#include <set>
#include <string_view>
#include <system_error>

#include "common/limits.h"
#include "common/scene_loader/obj_context.h"
#include "common/scene_loader/polygon.h"
#include "common/scene_loader/text.h"

namespace epr::loader {
namespace {

namespace fs = std::filesystem;

// Ear clipping takes time quadratic in a polygon's corners: a single face of 20000 corners took
// minutes. Real models' n-gons (cylinder caps) stay far below this.
constexpr size_t kMaxFaceCorners = 1024;
// Vertex and texture coordinate indices are kept as 32-bit integers.
constexpr size_t kMaxVertices = size_t(std::numeric_limits<int32_t>::max()) - 1;

/// Parses one face corner ("v", "v/vt", "v//vn", "v/vt/vn") into absolute 0-based indices (vt and vn
/// -1 if absent); returns the reason if malformed.
std::optional<std::string> parse_corner(std::string_view tok, size_t nv, size_t nvt, size_t nvn, uint32_t* v,
                                        int32_t* vt, int32_t* vn) {
  std::string_view parts[3];
  int count = 0;
  size_t start = 0;
  for (size_t i = 0; i <= tok.size(); ++i)
    if (i == tok.size() || tok[i] == '/') {
      if (count == 3) return fmt::format("face corner {} has more than three parts", quote_token(tok));
      parts[count++] = tok.substr(start, i - start);
      start = i + 1;
    }
  auto resolve = [&](std::string_view s, size_t defined, const char* what, int64_t* out) -> std::optional<std::string> {
    int64_t idx = 0;
    const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), idx);
    if (s.empty() || ec != std::errc() || ptr != s.data() + s.size())
      return fmt::format("bad {} index {} in face corner {}", what, quote_token(s), quote_token(tok));
    if (idx == 0) return fmt::format("{} index 0 in face corner {} (OBJ indices start at 1)", what, quote_token(tok));
    const int64_t n = int64_t(defined);
    const int64_t abs_idx = idx > 0 ? idx : n + idx + 1;
    if (abs_idx < 1 || abs_idx > n)
      return fmt::format("{} index {} is out of range: {} {} defined so far", what, idx, n, n == 1 ? "is" : "are");
    *out = abs_idx - 1;
    return std::nullopt;
  };
  if (count >= 2 && parts[count - 1].empty()) return fmt::format("face corner {} ends in '/'", quote_token(tok));
  int64_t index = 0;
  if (auto e = resolve(parts[0], nv, "vertex", &index)) return e;
  *v = uint32_t(index);
  *vt = -1;
  *vn = -1;
  if (count >= 2 && !parts[1].empty()) {  // "v//vn" has no texture coordinate
    if (auto e = resolve(parts[1], nvt, "texture coordinate", &index)) return e;
    *vt = int32_t(index);
  }
  if (count == 3) {
    if (auto e = resolve(parts[2], nvn, "normal", &index)) return e;
    *vn = int32_t(index);
  }
  return std::nullopt;
}

/// A triangle as read: per corner the vertex and the texture coordinate (-1: none), and the index
/// of its material in the material table (-1: none).
struct ObjTriangle {
  std::array<uint32_t, 3> v;
  std::array<int32_t, 3> vt;
  std::array<int32_t, 3> vn;
  int material;
};

struct ObjMesh {
  std::vector<Vec3> positions;
  std::vector<Vec2> texcoords;
  std::vector<Vec3> normals;  // vn, unit length
  std::vector<ObjTriangle> triangles;
  size_t first_degenerate_line = 0;  // first triangle face of zero area (0: none), for messages
};

/// Reads the OBJ text (and on the way its MTL files and textures) into a mesh.
ObjMesh read_obj(ObjContext& ctx, const FileRef& obj, const std::string& text) {
  const std::string& file = obj.display;
  const fs::path dir = obj.real.parent_path();
  const std::string display_dir = fs::path(obj.display).parent_path().string();

  ObjMesh mesh;
  size_t faces = 0, triangles = 0;
  int material = -1;
  std::vector<uint32_t> corner_v;
  std::vector<int32_t> corner_vt, corner_vn;
  std::vector<std::array<uint32_t, 3>> face_triangles;
  std::set<std::string, std::less<>> warned_keywords;
  StatementReader statements(text, file);
  while (statements.next()) {
    const size_t ln = statements.line_number();
    const std::string_view line = statements.line();
    const std::vector<std::string_view>& tok = statements.tokens();
    const std::string_view key = tok[0];
    if (key == "v") {
      if (tok.size() < 4 || tok.size() > 8)
        fail(file, ln, fmt::format("vertex needs 3 coordinates (x y z [w] [r g b]), got {}", tok.size() - 1));
      Vec3 p;
      for (int k = 0; k < 3; ++k) p[k] = parse_real(tok[size_t(k) + 1], limits::kMaxCoordinate, file, ln, "coordinate");
      for (size_t k = 4; k < tok.size(); ++k) parse_real(tok[k], 1e30, file, ln, "vertex weight or colour");
      if (mesh.positions.size() >= kMaxVertices) fail(file, ln, "too many vertices");
      mesh.positions.push_back(p);
    } else if (key == "vt") {
      if (tok.size() < 2 || tok.size() > 4)
        fail(file, ln, fmt::format("texture coordinate needs 1 to 3 numbers, got {}", tok.size() - 1));
      Vec2 uv{0.f, 0.f};
      for (size_t k = 1; k < tok.size(); ++k) {
        const float x = parse_real(tok[k], limits::kMaxCoordinate, file, ln, "texture coordinate");
        if (k == 1) uv.x = x;
        if (k == 2) uv.y = x;
      }
      if (mesh.texcoords.size() >= kMaxVertices) fail(file, ln, "too many texture coordinates");
      mesh.texcoords.push_back(uv);
    } else if (key == "vn") {
      if (tok.size() != 4) fail(file, ln, fmt::format("normal needs 3 numbers, got {}", tok.size() - 1));
      Vec3 n;
      for (int k = 0; k < 3; ++k) n[k] = parse_real(tok[size_t(k) + 1], 1e30, file, ln, "normal component");
      const float l = length(n);
      if (!(l > 0) || !std::isfinite(l)) fail(file, ln, "normal has zero length");
      if (mesh.normals.size() >= kMaxVertices) fail(file, ln, "too many normals");
      mesh.normals.push_back(n / l);
    } else if (key == "f") {
      const size_t n = tok.size() - 1;
      if (n < 3) fail(file, ln, fmt::format("face needs at least 3 vertices, got {}", n));
      if (n > kMaxFaceCorners)
        fail(file, ln, fmt::format("face has {} vertices, more than the {} supported", n, kMaxFaceCorners));
      triangles += n - 2;
      if (triangles > ctx.opts.max_triangles)
        fail(file, ln, fmt::format("more than {} triangles (the limit)", ctx.opts.max_triangles));
      corner_v.resize(n);
      corner_vt.resize(n);
      corner_vn.resize(n);
      for (size_t k = 0; k < n; ++k)
        if (auto err = parse_corner(tok[k + 1], mesh.positions.size(), mesh.texcoords.size(), mesh.normals.size(),
                                    &corner_v[k], &corner_vt[k], &corner_vn[k]))
          fail(file, ln, *err);
      ++faces;
      if (n == 3 && mesh.first_degenerate_line == 0) {  // build_scene's zero-area test
        const Vec3 &a = mesh.positions[corner_v[0]], &b = mesh.positions[corner_v[1]], &c = mesh.positions[corner_v[2]];
        if (!(length(cross(b - a, c - a)) > 0.f)) mesh.first_degenerate_line = ln;
      }
      face_triangles.clear();
      triangulate_face(mesh.positions, corner_v.data(), n, &face_triangles);
      for (const auto& t : face_triangles)
        mesh.triangles.push_back({{corner_v[t[0]], corner_v[t[1]], corner_v[t[2]]},
                                  {corner_vt[t[0]], corner_vt[t[1]], corner_vt[t[2]]},
                                  {corner_vn[t[0]], corner_vn[t[1]], corner_vn[t[2]]},
                                  material});
    } else if (key == "usemtl") {
      if (tok.size() < 2) fail(file, ln, "usemtl without a material name");
      const std::string name(tok[1]);
      if (!ctx.defined_materials.count(name))
        warn(ctx.report, fmt::format("{}:{}: material '{}' is not defined by an earlier mtllib; using the default grey",
                                     file, ln, name));
      const auto it = ctx.table.first_of_name.find(name);
      material = it == ctx.table.first_of_name.end() ? -1 : it->second;
    } else if (key == "mtllib") {
      const auto names = split_escaped(rest_after_keyword(line, key));
      if (names.empty()) fail(file, ln, "mtllib names no file");
      std::vector<FileRef> mtls;
      for (const std::string& name : names) {
        mtls.push_back(resolve_inside(ctx.root, dir, display_dir, name, file, ln, "mtllib"));
        if (auto problem = file_problem(mtls.back().real, ctx.opts.max_file_bytes))
          fail(file, ln, fmt::format("mtllib '{}' {}", name, *problem));
      }
      apply_mtllib(ctx, mtls, file, ln);
    } else {
      static const std::set<std::string, std::less<>> kIgnored = {"g", "o", "s", "l", "p", "vp"};
      if (!kIgnored.count(key) && warned_keywords.insert(std::string(key)).second)
        warn(ctx.report, fmt::format("{}:{}: unsupported statement {} ignored", file, ln, quote_token(key)));
    }
  }
  if (faces == 0) fail_file(file, "no faces");
  return mesh;
}

Vec3 clamped_colour(LoadReport& report, Vec3 v, float hi, const std::string& file, const std::string& material,
                    const char* what) {
  const Vec3 clamped(std::clamp(v.x, 0.f, hi), std::clamp(v.y, 0.f, hi), std::clamp(v.z, 0.f, hi));
  if (!(clamped == v))
    warn(report,
         fmt::format("{}: material '{}': {} ({}, {}, {}) clamped to [0, {}]", file, material, what, v.x, v.y, v.z, hi));
  return clamped;
}

/// The scene of a mesh read by read_obj: materials in table order (then the default grey if a face
/// has none), zero-area triangles dropped.
Scene build_scene(ObjContext& ctx, ObjMesh& mesh, const std::string& file, std::vector<GlossyDefaults>* glossy) {
  Scene scene;
  scene.name = file;
  scene.positions = std::move(mesh.positions);
  for (const MtlMaterial& m : ctx.table.materials) {
    Material mat;
    mat.name = m.name;
    mat.kd = clamped_colour(ctx.report, m.kd, 1.f, file, m.name, "Kd");
    mat.ke = clamped_colour(ctx.report, m.ke, 1e6f, file, m.name, "Ke");
    mat.emits_front_only = m.emit_front_only;
    mat.kd_texture = m.texture;
    if (m.mask >= 0 && !is_black(mat.ke))
      warn(ctx.report, fmt::format("{}: material '{}': map_d ignored: an emitter is not cut out", file, m.name));
    else
      mat.alpha_texture = m.mask;
    add_material(scene, std::move(mat));
    if (glossy)
      glossy->push_back({clamped_colour(ctx.report, m.ks, 1.f, file, m.name, "Ks"),
                         m.ns > 0 && std::isfinite(m.ns) ? m.ns : Material{}.exponent});
  }
  decode_textures(ctx);
  scene.textures = std::move(ctx.textures);

  int default_material = -1;
  size_t degenerate = 0;
  bool uses_texture = false, textured_without_uv = false;
  std::vector<std::array<Vec2, 3>> uvs;
  std::vector<std::array<Vec3, 3>> normals;
  bool smooth = false;
  scene.triangles.reserve(mesh.triangles.size());
  scene.material_of.reserve(mesh.triangles.size());
  for (const ObjTriangle& t : mesh.triangles) {
    const Vec3 &a = scene.positions[t.v[0]], &b = scene.positions[t.v[1]], &c = scene.positions[t.v[2]];
    if (!(length(cross(b - a, c - a)) > 0.f)) {
      ++degenerate;
      continue;
    }
    int mat = t.material;
    if (mat < 0) {
      if (default_material < 0) {
        Material grey;
        grey.name = "default";
        grey.kd = Vec3(0.8f);
        default_material = int(add_material(scene, grey));
        if (glossy) glossy->push_back({});
      }
      mat = default_material;
    }
    std::array<Vec2, 3> uv{};
    bool has_uv = true;
    for (int k = 0; k < 3; ++k) {
      if (t.vt[size_t(k)] >= 0)
        uv[size_t(k)] = mesh.texcoords[size_t(t.vt[size_t(k)])];
      else
        has_uv = false;
    }
    if (scene.materials[size_t(mat)].kd_texture >= 0 || scene.materials[size_t(mat)].cut_out()) {
      uses_texture = true;
      textured_without_uv |= !has_uv;
    }
    scene.triangles.push_back(t.v);
    scene.material_of.push_back(uint32_t(mat));
    uvs.push_back(uv);
    const Vec3 face = normalize(cross(b - a, c - a));
    std::array<Vec3, 3> n{face, face, face};
    for (size_t k = 0; k < 3; ++k)
      if (t.vn[k] >= 0) n[k] = mesh.normals[size_t(t.vn[k])], smooth = true;
    normals.push_back(n);
  }
  // Zero-area triangles are dropped, not fatal (exporters leave slivers behind); a scene of nothing but
  // them is an error. Both messages name the first zero-area triangle face when there is one (a
  // polygon's triangles are only known after triangulation).
  const size_t first_line = mesh.first_degenerate_line;
  const std::string where = first_line > 0 ? fmt::format("{}:{}", file, first_line) : file;
  const std::string first = first_line > 0 ? " (the first on this line)" : "";
  if (scene.triangles.empty())
    throw SceneError(fmt::format("{}: all {} triangles are degenerate (zero area){}", where, degenerate, first));
  if (degenerate > 0)
    warn(ctx.report, fmt::format("{}: dropped {} degenerate (zero-area) triangles{}", where, degenerate, first));
  if (uses_texture) scene.uvs = std::move(uvs);
  if (smooth) scene.normals = std::move(normals);
  if (textured_without_uv)
    warn(ctx.report, fmt::format("{}: some textured faces have no texture coordinates; they use texel (0, 0)", file));
  return scene;
}

}  // namespace

Scene load_obj_inside(const FileRef& obj, const fs::path& root, const LoadOptions& opts, LoadReport& report,
                      std::vector<GlossyDefaults>* glossy) {
  const std::string text = read_file(obj, opts.max_file_bytes, &report);
  ObjContext ctx(opts, root, report);
  ObjMesh mesh = read_obj(ctx, obj, text);
  return build_scene(ctx, mesh, obj.display, glossy);
}

}  // namespace epr::loader
