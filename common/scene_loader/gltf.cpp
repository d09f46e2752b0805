// glTF 2.0 scenes (scenes/README.md, "glTF 2.0"): the node tree flattened into world-space triangles,
// metallic-roughness materials mapped onto the scene's Lambertian / glossy / emissive materials, and
// the first camera node. Each approximation is a warning naming the file and the material, once.
#include "common/scene_loader/gltf.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstring>
#include <map>
#include <set>
#include <tuple>
#include <vector>

#include "common/limits.h"
#include "common/scene_loader/gltf_accessor.h"
#include "common/scene_loader/gltf_files.h"
#include "common/scene_loader/gltf_lights.h"
#include "common/scene_loader/gltf_materials.h"
#include "common/scene_loader/gltf_normals.h"
#include "common/scene_loader/obj_context.h"
#include "common/scene_loader/text.h"
#include "common/tangents.h"

namespace epr::loader {
namespace {

namespace fs = std::filesystem;
using Mat4 = std::array<double, 16>;  // column-major, as glTF writes matrices

constexpr double kPi = 3.14159265358979323846;

Mat4 identity() { return {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1}; }

Mat4 mul(const Mat4& a, const Mat4& b) {
  Mat4 r{};
  for (int c = 0; c < 4; ++c)
    for (int row = 0; row < 4; ++row) {
      double s = 0;
      for (int k = 0; k < 4; ++k) s += a[size_t(k * 4 + row)] * b[size_t(c * 4 + k)];
      r[size_t(c * 4 + row)] = s;
    }
  return r;
}

std::array<double, 3> transform_d(const Mat4& m, double x, double y, double z, double w) {
  return {m[0] * x + m[4] * y + m[8] * z + m[12] * w, m[1] * x + m[5] * y + m[9] * z + m[13] * w,
          m[2] * x + m[6] * y + m[10] * z + m[14] * w};
}

Vec3 transform(const Mat4& m, double x, double y, double z, double w) {
  const auto p = transform_d(m, x, y, z, w);
  return {float(p[0]), float(p[1]), float(p[2])};
}

bool within_limit(const std::array<double, 3>& p) { return limits::within_coordinate_limit(p[0], p[1], p[2]); }

double det3(const Mat4& m) {
  return m[0] * (m[5] * m[10] - m[9] * m[6]) - m[4] * (m[1] * m[10] - m[9] * m[2]) + m[8] * (m[1] * m[6] - m[5] * m[2]);
}

const char* mode_name(int mode) {
  switch (mode) {
    case TINYGLTF_MODE_POINTS:
      return "points";
    case TINYGLTF_MODE_LINE:
      return "lines";
    case TINYGLTF_MODE_LINE_LOOP:
      return "line loop";
    case TINYGLTF_MODE_LINE_STRIP:
      return "line strip";
    case TINYGLTF_MODE_TRIANGLE_STRIP:
      return "triangle strip";
    case TINYGLTF_MODE_TRIANGLE_FAN:
      return "triangle fan";
    default:
      return "unknown";
  }
}

class GltfReader {
 public:
  GltfReader(const FileRef& f, const fs::path& root, const LoadOptions& opts, LoadReport& report)
      : f_(f), root_(root), opts_(opts), report_(report), textures_(opts, root, report) {}

  Scene read() {
    read_gltf(f_, root_, opts_, report_, &in_);
    const tinygltf::Model& m = in_.model;
    if (m.scenes.empty()) error("no scenes: nothing to render");
    const int s = m.defaultScene >= 0 ? m.defaultScene : 0;
    if (size_t(s) >= m.scenes.size()) error(fmt::format("scene {} does not exist ({} scenes)", s, m.scenes.size()));
    if (!m.animations.empty()) note_once("animations ignored: the scene is loaded as it stands");
    if (!m.skins.empty()) note_once("skins ignored: meshes are placed by their nodes only");
    std::vector<std::string> light_notes;
    lights_ = read_gltf_lights(m, f_.display, &light_notes);
    for (const std::string& note : light_notes) note_once(note);
    visit(m.scenes[size_t(s)].nodes, fmt::format("scenes[{}]", s));
    if (scene_.triangles.empty()) error(no_triangles_reason(s));
    if (degenerate_ > 0)
      warn(report_, fmt::format("{}: dropped {} degenerate (zero-area) triangles, the first in {}", f_.display,
                                degenerate_, first_degenerate_));
    if (textured_) scene_.uvs = std::move(uvs_);
    if (smooth_) scene_.normals = std::move(normals_);
    if (mapped_) {
      scene_.tangents = std::move(tangents_);
      generate_tangents(scene_, tangent_needed_);
    }
    decode_textures(textures_);
    scene_.textures = std::move(textures_.textures);
    scene_.name = f_.display;
    return std::move(scene_);
  }

 private:
  [[noreturn]] void error(const std::string& reason) const { fail_file(f_.display, reason); }

  /// Why scenes[s] gave no triangle, naming the primitives it placed.
  std::string no_triangles_reason(int s) const {
    if (primitives_ == 0)
      return fmt::format("no triangles: no node of scenes[{}] holds a mesh ({} nodes, {} meshes in the file)", s,
                         in_.model.nodes.size(), in_.model.meshes.size());
    return fmt::format(
        "no triangles: the {} primitive(s) scenes[{}] places, the first {}, hold {} triangle(s): {} of zero area, {} "
        "cut out entirely by their material",
        primitives_, s, first_primitive_, degenerate_ + cut_out_, degenerate_, cut_out_);
  }

  void note_once(const std::string& what) {
    if (file_notes_.insert(what).second) warn(report_, fmt::format("{}: {}", f_.display, what));
  }

  /// Walks the node tree from `roots` depth-first, in order.
  void visit(const std::vector<int>& roots, const std::string& where) {
    const auto& nodes = in_.model.nodes;
    std::vector<bool> seen(nodes.size(), false);
    std::vector<std::pair<int, Mat4>> stack;
    auto push_children = [&](const std::vector<int>& children, const Mat4& parent, const std::string& from) {
      for (size_t i = children.size(); i-- > 0;) {
        const int n = children[i];
        if (n < 0 || size_t(n) >= nodes.size())
          error(fmt::format("{}: node {} does not exist ({} nodes)", from, n, nodes.size()));
        if (seen[size_t(n)]) error(fmt::format("nodes[{}] appears twice in the node tree (a node has one parent)", n));
        seen[size_t(n)] = true;
        stack.emplace_back(n, parent);
      }
    };
    push_children(roots, identity(), where);
    while (!stack.empty()) {
      auto [n, parent] = stack.back();
      stack.pop_back();
      const tinygltf::Node& node = nodes[size_t(n)];
      const Mat4 world = mul(parent, local_transform(node, n));
      if (node.mesh >= 0) add_mesh(node.mesh, world, n);
      if (node.camera >= 0 && !camera_found_) set_camera(node.camera, world, n);
      place_gltf_light(node, n, world, lights_, f_.display, &scene_.lights);
      push_children(node.children, world, fmt::format("nodes[{}].children", n));
    }
  }

  Mat4 local_transform(const tinygltf::Node& node, int n) const {
    const auto finite = [](const std::vector<double>& v) {
      return std::all_of(v.begin(), v.end(), [](double x) { return std::isfinite(x); });
    };
    if (!finite(node.matrix) || !finite(node.translation) || !finite(node.rotation) || !finite(node.scale))
      error(fmt::format("nodes[{}]: non-finite transform", n));
    if (!node.matrix.empty()) {
      if (node.matrix.size() != 16) error(fmt::format("nodes[{}]: matrix must have 16 numbers", n));
      Mat4 m;
      std::copy(node.matrix.begin(), node.matrix.end(), m.begin());
      return m;
    }
    Mat4 t = identity(), r = identity(), s = identity();
    if (!node.translation.empty()) {
      if (node.translation.size() != 3) error(fmt::format("nodes[{}]: translation must have 3 numbers", n));
      t[12] = node.translation[0], t[13] = node.translation[1], t[14] = node.translation[2];
    }
    if (!node.rotation.empty()) {
      if (node.rotation.size() != 4) error(fmt::format("nodes[{}]: rotation must have 4 numbers", n));
      double x = node.rotation[0], y = node.rotation[1], z = node.rotation[2], w = node.rotation[3];
      const double len = std::sqrt(x * x + y * y + z * z + w * w);
      if (!(len > 0)) error(fmt::format("nodes[{}]: rotation is not a unit quaternion", n));
      x /= len, y /= len, z /= len, w /= len;
      r = {1 - 2 * (y * y + z * z),
           2 * (x * y + z * w),
           2 * (x * z - y * w),
           0,
           2 * (x * y - z * w),
           1 - 2 * (x * x + z * z),
           2 * (y * z + x * w),
           0,
           2 * (x * z + y * w),
           2 * (y * z - x * w),
           1 - 2 * (x * x + y * y),
           0,
           0,
           0,
           0,
           1};
    }
    if (!node.scale.empty()) {
      if (node.scale.size() != 3) error(fmt::format("nodes[{}]: scale must have 3 numbers", n));
      s[0] = node.scale[0], s[5] = node.scale[1], s[10] = node.scale[2];
    }
    return mul(t, mul(r, s));
  }

  void set_camera(int c, const Mat4& world, int n) {
    const auto& cameras = in_.model.cameras;
    if (size_t(c) >= cameras.size())
      error(fmt::format("nodes[{}]: camera {} does not exist ({} cameras)", n, c, cameras.size()));
    camera_found_ = true;
    const tinygltf::Camera& cam = cameras[size_t(c)];
    if (cam.type != "perspective") {
      note_once(fmt::format("cameras[{}] is {}: only perspective cameras are read, the default camera is used", c,
                            quote_token(cam.type)));
      return;
    }
    CameraSpec spec;
    spec.eye = transform(world, 0, 0, 0, 1);
    const Vec3 forward = transform(world, 0, 0, -1, 0);
    spec.look = spec.eye + normalize(forward);
    spec.up = transform(world, 0, 1, 0, 0);
    spec.fov_y_degrees = float(cam.perspective.yfov * 180.0 / kPi);
    if (!(cam.perspective.yfov > 0 && cam.perspective.yfov < kPi))
      error(fmt::format("cameras[{}]: yfov {} is not between 0 and pi", c, cam.perspective.yfov));
    if (auto problem = spec.validate()) {
      note_once(fmt::format("nodes[{}]: camera placement unusable ({}), the default camera is used", n, *problem));
      return;
    }
    scene_.camera = spec;
  }

  View view(int a, const std::string& where, const char* role) const {
    return accessor_view(in_.model, a, where, role, f_.display);
  }

  void add_mesh(int mi, const Mat4& world, int n) {
    const auto& meshes = in_.model.meshes;
    if (size_t(mi) >= meshes.size())
      error(fmt::format("nodes[{}]: mesh {} does not exist ({} meshes)", n, mi, meshes.size()));
    for (size_t p = 0; p < meshes[size_t(mi)].primitives.size(); ++p)
      add_primitive(meshes[size_t(mi)].primitives[p], world, fmt::format("meshes[{}].primitives[{}]", mi, p), n);
  }

  /// Every element of the POSITION accessor `a` is finite and, placed by `world` (node n's transform
  /// with its parents'), within limits::kMaxCoordinate.
  void check_positions(const View& pos, int a, const Mat4& world, const std::string& where, int n) const {
    for (size_t i = 0; i < pos.count; ++i) {
      const std::array<double, 3> p{pos.get(i, 0), pos.get(i, 1), pos.get(i, 2)};
      const auto w = transform_d(world, p[0], p[1], p[2], 1);
      if (within_limit(p) && within_limit(w)) continue;
      const std::string element =
          fmt::format("{}: POSITION accessors[{}] element {} ({:g}, {:g}, {:g})", where, a, i, p[0], p[1], p[2]);
      if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) error(element + " is not finite");
      if (!within_limit(p))
        error(fmt::format("{} exceeds the magnitude limit {:g} (metres)", element, limits::kMaxCoordinate));
      error(
          fmt::format("{}, placed by nodes[{}] and its parents at ({:g}, {:g}, {:g}), exceeds the magnitude limit "
                      "{:g} (metres)",
                      element, n, w[0], w[1], w[2], limits::kMaxCoordinate));
    }
  }

  void add_primitive(const tinygltf::Primitive& prim, const Mat4& world, const std::string& where, int n) {
    if (prim.mode != TINYGLTF_MODE_TRIANGLES)
      error(fmt::format("{}: mode {} ({}) is not supported: only triangle lists (mode 4) are read", where, prim.mode,
                        mode_name(prim.mode)));
    const auto pos_it = prim.attributes.find("POSITION");
    if (pos_it == prim.attributes.end()) error(where + ": no POSITION attribute");
    const View pos = view(pos_it->second, where, "POSITION");
    const tinygltf::Accessor& pacc = in_.model.accessors[size_t(pos_it->second)];
    if (pacc.type != TINYGLTF_TYPE_VEC3 || pacc.componentType != TINYGLTF_COMPONENT_TYPE_FLOAT)
      error(where + ": POSITION must be float VEC3");
    check_positions(pos, pos_it->second, world, where, n);
    if (prim.attributes.count("COLOR_0")) note_once("vertex colours (COLOR_0) ignored");
    if (!prim.targets.empty()) note_once("morph targets ignored");
    if (prim.material >= 0 && size_t(prim.material) >= in_.model.materials.size())
      error(fmt::format("{}: material {} does not exist ({} materials)", where, prim.material,
                        in_.model.materials.size()));
    const auto [mat, texcoord] = material_for(prim.material);
    const bool mapped = scene_.materials[mat].normal_texture >= 0;
    const std::vector<Vec3> normals = read_normals(in_.model, prim, where, pos.count, world, f_.display);
    const std::vector<Tangent> tangents =
        mapped ? read_tangents(in_.model, prim, where, pos.count, world, f_.display) : std::vector<Tangent>{};
    smooth_ |= !normals.empty() || mapped;
    mapped_ |= mapped;

    View uv;
    bool has_uv = false;
    if (texcoord >= 0) {
      const auto uv_it = prim.attributes.find(fmt::format("TEXCOORD_{}", texcoord));
      if (uv_it == prim.attributes.end()) {
        note_once(fmt::format("{}: its material's texture needs TEXCOORD_{}, which it lacks: one texel is used", where,
                              texcoord));
      } else {
        uv = view(uv_it->second, where, "TEXCOORD");
        const tinygltf::Accessor& uacc = in_.model.accessors[size_t(uv_it->second)];
        if (uacc.type != TINYGLTF_TYPE_VEC2 || uv.count != pos.count ||
            !(uv.component == TINYGLTF_COMPONENT_TYPE_FLOAT || uv.normalized))
          error(where + ": TEXCOORD must be VEC2 (float or normalized) with one entry per POSITION");
        has_uv = true;
      }
      textured_ = true;
    }

    std::vector<uint32_t> index;
    if (prim.indices >= 0) {
      const View iv = view(prim.indices, where, "indices");
      const tinygltf::Accessor& iacc = in_.model.accessors[size_t(prim.indices)];
      if (iacc.type != TINYGLTF_TYPE_SCALAR || iacc.componentType == TINYGLTF_COMPONENT_TYPE_FLOAT ||
          iacc.componentType == TINYGLTF_COMPONENT_TYPE_BYTE || iacc.componentType == TINYGLTF_COMPONENT_TYPE_SHORT)
        error(where + ": indices must be unsigned integer scalars");
      if (iv.count % 3 != 0) error(fmt::format("{}: {} indices are not a whole number of triangles", where, iv.count));
      index.resize(iv.count);
      for (size_t i = 0; i < iv.count; ++i) {
        const double v = View{iv.base, iv.count, iv.stride, iv.component, false}.get(i, 0);
        if (v >= double(pos.count))
          error(
              fmt::format("{}: index {} (entry {}) is out of range: POSITION has {} vertices", where, v, i, pos.count));
        index[i] = uint32_t(v);
      }
    } else {
      if (pos.count % 3 != 0)
        error(fmt::format("{}: {} vertices without indices are not a whole number of triangles", where, pos.count));
    }
    const size_t corners = prim.indices >= 0 ? index.size() : pos.count;
    if (scene_.triangles.size() + corners / 3 > opts_.max_triangles)
      error(fmt::format("{}: more than {} triangles", where, opts_.max_triangles));
    if (primitives_++ == 0) first_primitive_ = where;
    if (hidden_.count(mat)) cut_out_ += corners / 3;
    const bool mirrored = det3(world) < 0;  // keeps the winding, and so the normals, as modelled
    for (size_t t = 0; t < corners && !hidden_.count(mat); t += 3) {
      std::array<size_t, 3> c{t, t + 1, t + 2};
      if (!index.empty()) c = {index[t], index[t + 1], index[t + 2]};
      if (mirrored) std::swap(c[1], c[2]);
      std::array<Vec3, 3> p, nc{};
      std::array<Vec2, 3> tc{};
      std::array<Tangent, 3> tan{};
      for (int k = 0; k < 3; ++k) {
        if (!normals.empty()) nc[size_t(k)] = normals[c[size_t(k)]];
        if (!tangents.empty()) tan[size_t(k)] = tangents[c[size_t(k)]];
        p[size_t(k)] =
            transform(world, pos.get(c[size_t(k)], 0), pos.get(c[size_t(k)], 1), pos.get(c[size_t(k)], 2), 1);
        if (has_uv) tc[size_t(k)] = {float(uv.get(c[size_t(k)], 0)), float(1.0 - uv.get(c[size_t(k)], 1))};
      }
      if (!(length(cross(p[1] - p[0], p[2] - p[0])) > 0.f)) {
        if (degenerate_++ == 0) first_degenerate_ = where;
        continue;
      }
      const uint32_t base = uint32_t(scene_.positions.size());
      scene_.positions.insert(scene_.positions.end(), p.begin(), p.end());
      scene_.triangles.push_back({base, base + 1, base + 2});
      scene_.material_of.push_back(mat);
      uvs_.push_back(tc);
      const Vec3 face = normalize(cross(p[1] - p[0], p[2] - p[0]));  // glTF: flat where NORMAL is absent
      for (Vec3& nk : nc)
        if (!(length(nk) > 0.f)) nk = face;
      normals_.push_back(nc);
      tangents_.push_back(tan);
      tangent_needed_.push_back(mapped && tangents.empty());
    }
  }

  /// The scene material for glTF material `gi` (-1: the default) and the texture coordinate set its
  /// texture uses (-1 if untextured), converted on first use.
  std::pair<uint32_t, int> material_for(int gi) {
    if (auto it = materials_.find(gi); it != materials_.end()) return it->second;
    std::pair<uint32_t, int> made;
    if (gi < 0) {
      Material def;
      def.name = "default";
      made = {add_material(scene_, def), -1};
    } else {
      made = convert_material(gi);
    }
    materials_.emplace(gi, made);
    return made;
  }

  std::pair<uint32_t, int> convert_material(int gi);
  /// alphaMode MASK (BLEND as MASK): sets out's mask and cut-off; true if the whole surface is cut out.
  bool set_cut_out(const tinygltf::Material& gm, const std::string& where, Material* out,
                   std::vector<std::string>* notes);
  /// The texture of `info` times `factor`, or (alpha) its plain image with the alpha mask read.
  int texture_for(const tinygltf::TextureInfo& info, Vec3 factor, const std::string& where, bool alpha = false);
  int image_texture(int image, bool alpha);
  /// The image of glTF texture `index` read with texCoord `texcoord`, checked; its sampler's NEAREST
  /// magFilter is noted for the scene texture `apply_sampler` gives it.
  int image_of(int index, int texcoord, const std::string& where) const;
  void apply_sampler(int index, int texture);
  /// A normalTexture's image as stored (linear data), one scene texture per image.
  int normal_texture(int index, int texcoord, const std::string& where);
  /// Appends a texture made here (a copy with a factor, a derived one), within the pixel limit.
  int add_texture(Texture t, const std::string& what);

  const FileRef& f_;
  fs::path root_;
  const LoadOptions& opts_;
  LoadReport& report_;
  GltfInput in_;
  ObjContext textures_;  // the textures read so far (shared with the OBJ reader's texture loading)
  std::map<int, int> texture_of_image_, normal_of_image_;
  std::map<std::tuple<int, float, float, float>, int> baked_;  // (image, factor) -> texture
  std::map<int, std::pair<uint32_t, int>> materials_;
  std::set<uint32_t> hidden_;  // materials whose surface is cut out entirely: their triangles are dropped
  std::set<std::string> file_notes_;
  Scene scene_;
  std::vector<PunctualLight> lights_;  // KHR_lights_punctual's, in light space
  std::vector<std::array<Vec2, 3>> uvs_;
  std::vector<std::array<Vec3, 3>> normals_;  // per triangle; kept if some primitive has NORMAL or a normal map
  std::vector<std::array<Tangent, 3>> tangents_;
  std::vector<bool> tangent_needed_;  // a normal-mapped triangle without TANGENT: generated
  bool textured_ = false, camera_found_ = false, smooth_ = false, mapped_ = false;
  size_t degenerate_ = 0, cut_out_ = 0, primitives_ = 0;
  std::string first_degenerate_, first_primitive_;
};

std::pair<uint32_t, int> GltfReader::convert_material(int gi) {
  const tinygltf::Material& gm = in_.model.materials[size_t(gi)];
  const std::string where = fmt::format("materials[{}]", gi);
  const tinygltf::PbrMetallicRoughness& pbr = gm.pbrMetallicRoughness;
  const auto finite = [](const std::vector<double>& v) {
    return std::all_of(v.begin(), v.end(), [](double x) { return std::isfinite(x); });
  };
  if (pbr.baseColorFactor.size() != 4 || !finite(pbr.baseColorFactor))
    error(where + ": baseColorFactor must be 4 finite numbers");
  if (gm.emissiveFactor.size() != 3 || !finite(gm.emissiveFactor))
    error(where + ": emissiveFactor must be 3 finite numbers");
  if (!std::isfinite(pbr.metallicFactor) || !std::isfinite(pbr.roughnessFactor) || !std::isfinite(gm.alphaCutoff))
    error(where + ": metallicFactor, roughnessFactor and alphaCutoff must be finite");
  std::vector<std::string> notes;
  Material out;
  out.name = gm.name.empty() ? where : gm.name;
  const GltfMaterialContext context{f_.display,
                                    [this](const tinygltf::TextureInfo& info, Vec3 factor, const std::string& w) {
                                      return texture_for(info, factor, w);
                                    },
                                    [this](int i) -> const Texture& { return texels(textures_, i); },
                                    [this](Texture t, const std::string& w) { return add_texture(std::move(t), w); }};
  int texcoord = set_metallic_roughness(gm, where, context, &out, &notes);
  set_emission(gm, where, context, &out, &notes, &texcoord);

  const bool hidden = set_cut_out(gm, where, &out, &notes);
  if (gm.normalTexture.index >= 0) {
    const tinygltf::NormalTextureInfo& nt = gm.normalTexture;
    const std::string nw = where + ".normalTexture";
    if (!std::isfinite(nt.scale)) error(nw + ": scale must be finite");
    out.normal_texture = normal_texture(nt.index, nt.texCoord, nw);
    out.normal_scale = float(nt.scale);
    if (texcoord < 0) texcoord = nt.texCoord;
    if (texcoord != nt.texCoord)
      notes.push_back(fmt::format("normalTexture read with TEXCOORD_{} (the base colour's), not TEXCOORD_{}", texcoord,
                                  nt.texCoord));
  }
  if (gm.occlusionTexture.index >= 0) notes.push_back("occlusionTexture ignored");
  for (const auto& [name, value] : gm.extensions)
    if (!read_material_extension(name)) notes.push_back(fmt::format("extension {} ignored", quote_token(name)));
  if (!notes.empty())
    warn(report_,
         fmt::format("{}: material {} ({}): {}", f_.display, quote_token(out.name), where, fmt::join(notes, "; ")));
  const uint32_t index = add_material(scene_, out);
  if (hidden) hidden_.insert(index);
  return {index, texcoord};
}

bool GltfReader::set_cut_out(const tinygltf::Material& gm, const std::string& where, Material* out,
                             std::vector<std::string>* notes) {
  if (gm.alphaMode != "MASK" && gm.alphaMode != "BLEND") {
    if (gm.alphaMode != "OPAQUE" && !gm.alphaMode.empty())
      error(fmt::format("{}: alphaMode {} is not OPAQUE, MASK or BLEND", where, quote_token(gm.alphaMode)));
    return false;
  }
  const tinygltf::PbrMetallicRoughness& pbr = gm.pbrMetallicRoughness;
  float cutoff = float(gm.alphaCutoff);
  if (gm.alphaMode == "BLEND") {
    cutoff = 0.5f;
    notes->push_back("alphaMode BLEND rendered as MASK with alphaCutoff 0.5 (no partial transparency)");
  }
  if (out->emissive()) {
    notes->push_back(fmt::format("alphaMode {} ignored: an emitter is not cut out", gm.alphaMode));
    return false;
  }
  // alpha = baseColorFactor.a x texture alpha >= cutoff  <=>  texture alpha >= cutoff / a.
  const float a = float(std::clamp(pbr.baseColorFactor[3], 0.0, 1.0));
  if (!(cutoff > 0.f)) return false;  // nothing is below the cut-off
  if (a < cutoff && (pbr.baseColorTexture.index < 0 || a <= 0.f)) {
    notes->push_back(
        fmt::format("baseColorFactor alpha {:g} is below alphaCutoff {:g}: the surface is not rendered", a, cutoff));
    return true;
  }
  if (pbr.baseColorTexture.index < 0) return false;  // a constant alpha at or above the cut-off
  out->alpha_texture =
      texture_for(pbr.baseColorTexture, Vec3(1.f), where + ".pbrMetallicRoughness.baseColorTexture", true);
  out->alpha_cutoff = cutoff / a;
  return false;
}

int GltfReader::image_of(int index, int texcoord, const std::string& where) const {
  const auto& textures = in_.model.textures;
  if (index < 0 || size_t(index) >= textures.size())
    error(fmt::format("{}: texture {} does not exist ({} textures)", where, index, textures.size()));
  if (texcoord < 0 || texcoord > 7) error(fmt::format("{}: texCoord {} is not 0..7", where, texcoord));
  const int image = textures[size_t(index)].source;
  if (image < 0 || size_t(image) >= in_.model.images.size())
    error(fmt::format("{}: textures[{}] has no image (source {})", where, index, image));
  return image;
}

void GltfReader::apply_sampler(int index, int texture) {
  const int sampler = in_.model.textures[size_t(index)].sampler;
  if (sampler >= 0 && size_t(sampler) < in_.model.samplers.size() &&
      in_.model.samplers[size_t(sampler)].magFilter == TINYGLTF_TEXTURE_FILTER_NEAREST)
    textures_.textures[size_t(texture)].nearest = true;
}

int GltfReader::normal_texture(int index, int texcoord, const std::string& where) {
  const int image = image_of(index, texcoord, where);
  int t;
  if (auto it = normal_of_image_.find(image); it != normal_of_image_.end()) {
    t = it->second;
  } else {
    const tinygltf::Image& img = in_.model.images[size_t(image)];
    const std::string iw = fmt::format("{}: images[{}]", f_.display, image);
    if (auto e = in_.embedded_images.find(image); e != in_.embedded_images.end()) {
      const std::string name = img.name.empty() ? fmt::format("images[{}]", image) : img.name;
      textures_.textures.push_back(
          decode_image_bytes(e->second, name, iw, opts_, &textures_.texture_pixels, false, true));
      t = int(textures_.textures.size() - 1);
    } else if (!img.uri.empty()) {
      t = load_texture(textures_, decode_uri(img.uri), in_.dir, in_.display_dir, iw, 0, TextureUse::kData);
    } else {
      fail_file(iw, "the image has neither data nor a uri");
    }
    normal_of_image_[image] = t;
  }
  apply_sampler(index, t);
  return t;
}

int GltfReader::texture_for(const tinygltf::TextureInfo& info, Vec3 factor, const std::string& where, bool alpha) {
  const int image = image_of(info.index, info.texCoord, where);
  const int plain = image_texture(image, alpha);
  if (!alpha) apply_sampler(info.index, plain);
  if (factor == Vec3(1.f) || alpha) return plain;
  // A colour factor other than white is baked into a copy of the texture.
  const auto key = std::make_tuple(image, factor.x, factor.y, factor.z);
  if (auto it = baked_.find(key); it != baked_.end()) return it->second;
  Texture t = texels(textures_, plain);
  t.alpha.clear();  // a colour copy: the mask, if any, stays with the plain texture
  for (size_t i = 0; i < t.rgb.size(); ++i) t.rgb[i] = std::clamp(t.rgb[i] * factor[int(i % 3)], 0.f, 1.f);
  const int index = add_texture(std::move(t), fmt::format("{}: the factor's copy of image {}", where, image));
  baked_.emplace(key, index);
  return index;
}

int GltfReader::add_texture(Texture t, const std::string& what) {
  const size_t pixels = size_t(t.width) * size_t(t.height);
  if (pixels + textures_.texture_pixels > opts_.max_texture_pixels)
    error(fmt::format("{} takes the scene's textures over the limit of {} pixels", what, opts_.max_texture_pixels));
  textures_.texture_pixels += pixels;
  textures_.textures.push_back(std::move(t));
  return int(textures_.textures.size() - 1);
}

int GltfReader::image_texture(int image, bool alpha) {
  const auto cached = texture_of_image_.find(image);
  if (cached != texture_of_image_.end() && (!alpha || !textures_.textures[size_t(cached->second)].alpha.empty()))
    return cached->second;
  const tinygltf::Image& img = in_.model.images[size_t(image)];
  const std::string where = fmt::format("{}: images[{}]", f_.display, image);
  int index;
  if (auto it = in_.embedded_images.find(image); it != in_.embedded_images.end()) {
    const std::string name = img.name.empty() ? fmt::format("images[{}]", image) : img.name;
    if (cached != texture_of_image_.end()) {  // decoded before for its colour: the alpha as well now
      size_t again = 0;
      Texture& t = textures_.textures[size_t(cached->second)];
      t.alpha = decode_image_bytes(it->second, name, where, opts_, &again, true).alpha;
      return cached->second;
    }
    textures_.textures.push_back(decode_image_bytes(it->second, name, where, opts_, &textures_.texture_pixels, alpha));
    index = int(textures_.textures.size() - 1);
  } else if (!img.uri.empty()) {
    index = load_texture(textures_, decode_uri(img.uri), in_.dir, in_.display_dir, where, 0,
                         alpha ? TextureUse::kAlpha : TextureUse::kColour);
  } else {
    fail_file(where, "the image has neither data nor a uri");
  }
  texture_of_image_[image] = index;
  return index;
}

}  // namespace

bool is_gltf_path(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext == ".gltf" || ext == ".glb";
}

Scene load_gltf_inside(const FileRef& f, const fs::path& root, const LoadOptions& opts, LoadReport& report) {
  return GltfReader(f, root, opts, report).read();
}

}  // namespace epr::loader
