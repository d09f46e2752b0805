// The files of a glTF 2.0 scene: the .gltf or .glb file, its buffers and its images, read inside the
// scene folder and parsed by tinygltf. Every uri is checked before tinygltf sees the file: external
// files must lie inside the scene folder (as OBJ's mtllib and map_Kd), data URIs are limited in size,
// and tinygltf reads only the files checked here, through read_file().
#pragma once

// Images are decoded by the loader (OpenImageIO, with its size limits), not by tinygltf's stb_image.
#define TINYGLTF_NO_STB_IMAGE
#define TINYGLTF_NO_STB_IMAGE_WRITE
#define TINYGLTF_NO_EXTERNAL_IMAGE
#include <tiny_gltf.h>

#include <cstddef>
#include <filesystem>
#include <map>
#include <string>

#include "common/scene.h"
#include "common/scene_error.h"

namespace epr::loader {

/// Decoded data URIs may hold at most this many bytes each: larger data belongs in a .bin file.
constexpr size_t kMaxGltfDataUriBytes = size_t(16) << 20;

/// The extensions a glTF file may require (extensionsRequired): any other is refused, naming it.
inline constexpr const char* kSupportedGltfExtensions[] = {"KHR_materials_emissive_strength", "KHR_lights_punctual",
                                                           "KHR_materials_transmission", "KHR_materials_ior"};

/// A glTF file as tinygltf parsed it, with what the loader needs to read its images.
struct GltfInput {
  tinygltf::Model model;
  std::map<int, std::string> embedded_images;  // image index -> encoded bytes (bufferView or data URI)
  std::filesystem::path dir;                   // the glTF file's folder (canonical)
  std::string display_dir;                     // the same as the user named it
};

/// Reads `f` (.gltf or .glb by its extension), reading nothing outside `root`; the files read go to
/// report.files, the glTF file first. Failures raise SceneError "file: element: reason".
void read_gltf(const FileRef& f, const std::filesystem::path& root, const LoadOptions& opts, LoadReport& report,
               GltfInput* out);

/// Decodes an image held in memory (PNG, JPEG...), `name` and `where` naming it in messages; the
/// scene's texture pixels so far are in *pixels, checked against the limit before decoding. With
/// `alpha` the Texture's alpha mask is filled too (1 where the image has no alpha channel). With
/// `data` (a normal map) 8- and 16-bit values are read as stored, not as sRGB-encoded colour.
Texture decode_image_bytes(const std::string& bytes, const std::string& name, const std::string& where,
                           const LoadOptions& opts, size_t* pixels, bool alpha = false, bool data = false);

/// tinygltf's percent-decoding of uris, so that the file checked is the one tinygltf asks for.
std::string decode_uri(const std::string& uri);

}  // namespace epr::loader
