// Scenes as bytes: what a job carries so that workers need no shared file system (DESIGN.md
// section 2). A bundle is the entry file plus every file it references (MTL libraries, textures, the
// OBJ a scene JSON names), with relative '/'-separated paths; its content hash (proto/epr/v1/
// scene.proto gives the canonical serialisation) is the cache key on master and workers.
#pragma once

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "common/scene.h"
#include "wire/sha256.h"

namespace epr {

struct SceneBundleData {
  std::string builtin;     // "builtin:NAME?..." for generated scenes; then files is empty
  std::string entry_path;  // relative path of the file the loader starts from
  std::vector<std::pair<std::string, std::string>> files;  // (relative path, bytes)
  // The files the scene's load read on this machine (canonical paths), for the client's checks
  // (an output prefix must not replace one); not part of the bundle's content.
  std::vector<std::filesystem::path> sources;
  // The scene bundle_scene loaded (its own lighting, not the job's), for this process's other users of
  // it (wire/scene_shelf.h); not part of the bundle's content. Null for built-ins and received bundles.
  std::shared_ptr<const Scene> loaded;
  // The scene's own camera, from bundle_scene's load (either kind); not part of the bundle's content.
  std::optional<CameraSpec> camera;

  size_t total_bytes() const;
};

/// Loads `spec` (OBJ path, scene JSON path or builtin:NAME) as load_job_scene() does (its warnings
/// logged once, a scene without light refused) and bundles the files that load read. Throws
/// SceneError naming the file when the scene is broken, unlit, or a file cannot be read.
/// With `job`'s lighting (RenderOptions::lighting), an environment image it names is bundled too.
/// With a built-in scene, that image is read inside `env_folder` (RenderOptions::env_folder) and the
/// bundle is a scene JSON {"builtin": NAME} beside it (builtin stays empty); without `env_folder` it is
/// refused with the reason.
/// With kShare the scene that load gave stays in `loaded`; with kUpload its texture files are checked
/// (file, header, the size limits) but not decoded, and `loaded` stays null.
enum class BundleLoad : uint8_t {
  kShare,   // the scene is rendered in this process too (the embedded render)
  kUpload,  // the scene is only sent: a master and its workers load it
};
SceneBundleData bundle_scene(const std::string& spec, const Lighting& job = {}, const std::string& env_folder = "",
                             BundleLoad load = BundleLoad::kShare);

/// Lowercase hex SHA-256 over the canonical serialisation (files) or "epr-builtin-v1\n" + builtin.
std::string content_hash(const SceneBundleData& bundle);

/// Checks a relative path: no leading '/', no '\', no NUL byte, no empty, "." or ".." components,
/// <= 1024 bytes.
bool is_safe_relative_path(const std::string& path);

/// Writes the bundle's files below `cache_root`/HASH/ (once; an existing complete copy is reused)
/// and loads the scene, its warnings at debug level only, with `job`'s lighting applied (job_lighting);
/// a scene without light (unlit_reason) is refused with SceneError. Built-ins are generated directly.
Scene load_bundle(const SceneBundleData& bundle, const std::string& cache_root, const Lighting& job = {});

/// The same scene shared in this process: the one on the scene shelf (wire/scene_shelf.h) under the
/// bundle's content hash (`hash`, content_hash(bundle), which the caller has) if a user holds one, else
/// loaded as load_bundle loads it and shelved. The scene keeps its own lighting; like load_bundle, it
/// is refused with SceneError if unlit under `job`'s lighting.
std::shared_ptr<const Scene> share_bundle_scene(const SceneBundleData& bundle, const std::string& hash,
                                                const std::string& cache_root, const Lighting& job = {});

/// Writes the bundle's files below `cache_root`/HASH/ as load_bundle does (`hash`: content_hash(bundle))
/// and returns the entry file's path there. Throws SceneError for an unsafe path or a failed write.
std::string write_bundle_files(const SceneBundleData& bundle, const std::string& hash, const std::string& cache_root);

/// The folder scenes are cached in: $EPR_CACHE_DIR, else $XDG_CACHE_HOME/eprfarm, else ~/.cache/eprfarm.
std::string default_cache_root();

}  // namespace epr
