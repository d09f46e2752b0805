// glTF's metallic-roughness materials (with KHR_materials_transmission, KHR_materials_ior and
// KHR_materials_emissive_strength) onto the scene's kMicrofacet material (common/scene.h,
// worker/bsdf_ggx.h), for the glTF reader (gltf.cpp), which owns the textures.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "common/scene_loader/gltf_files.h"

namespace epr::loader {

/// The glTF reader's file and textures, as the material conversion needs them.
struct GltfMaterialContext {
  std::string file;  // the file's name in messages
  /// The colour texture `info` names (sRGB decoded, clamped to [0, 1]) times `factor` (a copy
  /// unless white); its index in the scene's textures. `where` names the reference in messages.
  std::function<int(const tinygltf::TextureInfo& info, Vec3 factor, const std::string& where)> colour;
  /// The scene's texture `index`.
  std::function<const Texture&(int index)> get;
  /// Appends a texture derived from another, counted against the scene's texture pixel limit.
  std::function<int(Texture t, const std::string& where)> add;
};

/// Makes *out a kMicrofacet material from glTF material gm (`where`: "materials[i]"): base colour
/// (factor times texture), metallic and roughness (factors, and metallicRoughnessTexture: Material
/// says how it is read), transmission and ior. Returns the TEXCOORD set its textures use (-1:
/// none); approximations are appended to *notes.
int set_metallic_roughness(const tinygltf::Material& gm, const std::string& where, const GltfMaterialContext& tex,
                           Material* out, std::vector<std::string>* notes);

/// Sets out->ke (emissiveFactor x emissiveStrength x the emission texture's mean) and, with an
/// emissiveTexture, out->ke_texture (the texture over its mean per channel). *texcoord is the set
/// the material's other textures use (-1: none yet), updated.
void set_emission(const tinygltf::Material& gm, const std::string& where, const GltfMaterialContext& tex, Material* out,
                  std::vector<std::string>* notes, int* texcoord);

/// True for the material extensions the two functions above read.
bool read_material_extension(const std::string& name);

}  // namespace epr::loader
