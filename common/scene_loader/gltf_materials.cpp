#include "common/scene_loader/gltf_materials.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "common/scene_loader/text.h"

namespace epr::loader {
namespace {

float clamp01(double v) { return float(std::clamp(v, 0.0, 1.0)); }

/// The texture set of `info`, checked against the one the material's other textures use.
void use_texcoord(const tinygltf::TextureInfo& info, int* texcoord, std::vector<std::string>* notes) {
  if (*texcoord < 0) {
    *texcoord = info.texCoord;
  } else if (*texcoord != info.texCoord) {
    notes->push_back(fmt::format("textures use TEXCOORD_{} and TEXCOORD_{}: TEXCOORD_{} is used for all", *texcoord,
                                 info.texCoord, *texcoord));
  }
}

/// The number `key` of extension `ext` of gm, or `fallback` without one; an error naming `where`
/// unless it lies in [lo, hi].
double extension_number(const tinygltf::Material& gm, const char* ext, const char* key, double fallback, double lo,
                        double hi, const std::string& file, const std::string& where) {
  const auto it = gm.extensions.find(ext);
  if (it == gm.extensions.end() || !it->second.Has(key)) return fallback;
  const tinygltf::Value& v = it->second.Get(key);
  const double x = v.IsNumber() ? v.GetNumberAsDouble() : std::nan("");
  if (!(x >= lo && x <= hi))
    fail_file(file, fmt::format("{}: {}.{} must be a number in [{:g}, {:g}]", where, ext, key, lo, hi));
  return x;
}

}  // namespace

int set_metallic_roughness(const tinygltf::Material& gm, const std::string& where, const GltfMaterialContext& tex,
                           Material* out, std::vector<std::string>* notes) {
  const tinygltf::PbrMetallicRoughness& pbr = gm.pbrMetallicRoughness;
  const Vec3 base{clamp01(pbr.baseColorFactor[0]), clamp01(pbr.baseColorFactor[1]), clamp01(pbr.baseColorFactor[2])};
  out->type = MaterialType::kMicrofacet;
  out->metallic = clamp01(pbr.metallicFactor);
  out->roughness = clamp01(pbr.roughnessFactor);
  int texcoord = -1;
  if (pbr.baseColorTexture.index >= 0) {
    out->kd_texture = tex.colour(pbr.baseColorTexture, base, where + ".pbrMetallicRoughness.baseColorTexture");
    use_texcoord(pbr.baseColorTexture, &texcoord, notes);
    if (!pbr.baseColorTexture.extensions.empty()) notes->push_back("texture extensions (texture transforms) ignored");
  } else {
    out->kd = base;
  }
  if (pbr.metallicRoughnessTexture.index >= 0) {
    // The image as decoded for colour (no copy: scenes such as Sponza fill the texture pixel limit
    // with their images alone); the worker undoes the sRGB curve per lookup (Material).
    out->metallic_roughness_texture =
        tex.colour(pbr.metallicRoughnessTexture, Vec3(1.f), where + ".pbrMetallicRoughness.metallicRoughnessTexture");
    use_texcoord(pbr.metallicRoughnessTexture, &texcoord, notes);
  }
  out->transmission =
      float(extension_number(gm, "KHR_materials_transmission", "transmissionFactor", 0, 0, 1, tex.file, where));
  if (auto it = gm.extensions.find("KHR_materials_transmission");
      it != gm.extensions.end() && it->second.Has("transmissionTexture"))
    notes->push_back("transmissionTexture ignored (transmissionFactor used)");
  if (out->transmission > 0)
    notes->push_back(
        "transmission rendered as solid glass refracting at each surface (KHR_materials_volume and the thin-walled "
        "default are not modelled)");
  const double ior = extension_number(gm, "KHR_materials_ior", "ior", 1.5, 0, 10, tex.file, where);
  if (ior > 0 && ior < 1) fail_file(tex.file, fmt::format("{}: KHR_materials_ior.ior {:g} is below 1", where, ior));
  out->ior = ior == 0 ? 10.f : float(ior);  // 0: an infinite index, as good as 10 for the Fresnel factor
  return texcoord;
}

void set_emission(const tinygltf::Material& gm, const std::string& where, const GltfMaterialContext& tex, Material* out,
                  std::vector<std::string>* notes, int* texcoord) {
  Vec3 ke{float(gm.emissiveFactor[0]), float(gm.emissiveFactor[1]), float(gm.emissiveFactor[2])};
  ke = ke *
       float(extension_number(gm, "KHR_materials_emissive_strength", "emissiveStrength", 1, 0, 1e9, tex.file, where));
  for (int k = 0; k < 3; ++k)
    if (!(ke[k] >= 0.f)) fail_file(tex.file, where + ": emissiveFactor must not be negative");
  if (gm.emissiveTexture.index >= 0 && !is_black(ke)) {
    const std::string w = where + ".emissiveTexture";
    Texture t = tex.get(tex.colour(gm.emissiveTexture, Vec3(1.f), w));
    t.alpha.clear();
    t.path += " (emission)";
    double sum[3] = {0, 0, 0};
    for (size_t i = 0; i < t.rgb.size(); ++i) sum[i % 3] += t.rgb[i];
    const double n = std::max<double>(1, double(t.rgb.size() / 3));
    const Vec3 mean(float(sum[0] / n), float(sum[1] / n), float(sum[2] / n));
    // Ke becomes the mean emitted radiance (what the emitter table's power and selection use) and
    // the texture its variation about the mean, so that Ke x texel is emissiveFactor x texel.
    for (size_t i = 0; i < t.rgb.size(); ++i) t.rgb[i] = mean[int(i % 3)] > 0 ? t.rgb[i] / mean[int(i % 3)] : 0.f;
    ke = ke * mean;
    if (is_black(ke)) {
      notes->push_back("emissiveTexture is black: the surface does not emit");
    } else {
      out->ke_texture = tex.add(std::move(t), w);
      use_texcoord(gm.emissiveTexture, texcoord, notes);
    }
  }
  out->ke = ke;
}

bool read_material_extension(const std::string& name) {
  return name == "KHR_materials_emissive_strength" || name == "KHR_materials_transmission" ||
         name == "KHR_materials_ior";
}

}  // namespace epr::loader
