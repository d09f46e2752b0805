// Scene bundles (scene_bundle.h): made from the files the loader reads, hashed, cached and loaded.
#include "wire/scene_bundle.h"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "common/scene_loader.h"
#include "wire/scene_shelf.h"

namespace epr {
namespace fs = std::filesystem;
size_t SceneBundleData::total_bytes() const {
  size_t n = 0;
  for (const auto& f : files) n += f.second.size();
  return n;
}

bool is_safe_relative_path(const std::string& path) {
  if (path.empty() || path.size() > 1024 || path[0] == '/' || path.find('\\') != std::string::npos) return false;
  if (path.find('\0') != std::string::npos) return false;  // a file name would end there
  std::istringstream in(path);
  std::string part;
  size_t parts = 0;
  while (std::getline(in, part, '/')) {
    if (part.empty() || part == "." || part == "..") return false;
    ++parts;
  }
  return parts > 0 && path.back() != '/';
}

namespace {

// A built-in scene with a job's environment image: a scene JSON naming the built-in, beside the
// image, so that the image travels as a scene JSON's files do. Without `env_folder` (where the image
// lies) the image is refused with the reason, as a built-in has no folder.
SceneBundleData bundle_builtin_with_image(const std::string& spec, const Lighting& job, const std::string& env_folder) {
  const LoadOptions opts;
  LoadReport report;
  load_job_scene(spec, opts, &report, job, env_folder);  // reads and checks the image
  if (report.files.size() != 1) throw SceneError(fmt::format("{}: expected the environment image alone", spec));
  const FileRef& image = report.files.front();
  const std::string name = image.real.filename().string();
  if (!is_safe_relative_path(name) || name != job.environment->image)
    throw SceneError(fmt::format("{}: environment image '{}' is not a file name", spec, job.environment->image));
  SceneBundleData b;
  b.entry_path = name == "builtin.json" ? "builtin-scene.json" : "builtin.json";
  b.files.emplace_back(b.entry_path, nlohmann::json{{"builtin", spec.substr(8)}}.dump() + "\n");
  b.files.emplace_back(name, read_scene_file(image, opts.max_file_bytes));
  b.sources.push_back(image.real);
  std::sort(b.files.begin(), b.files.end());
  return b;
}

}  // namespace

SceneBundleData bundle_scene(const std::string& spec, const Lighting& job, const std::string& env_folder,
                             BundleLoad load) {
  SceneBundleData b;
  if (spec.rfind("builtin:", 0) == 0 && spec.find('\0') == std::string::npos) {
    if (job.environment && !job.environment->image.empty()) return bundle_builtin_with_image(spec, job, env_folder);
    b.builtin = spec;
    return b;
  }
  // The scene is loaded here, so that its files are the ones the loader reads (one parser for both),
  // its warnings are shown once, on the user's side, and a broken or unlit scene fails before upload.
  LoadOptions opts;
  opts.decode_textures = load == BundleLoad::kShare;
  LoadReport report;
  Lighting job_lit;
  auto scene = std::make_shared<const Scene>(load_job_scene(spec, opts, &report, job, "", &job_lit));
  b.camera = scene->camera;
  if (load == BundleLoad::kShare) b.loaded = std::move(scene);
  if (report.files.empty()) throw SceneError(fmt::format("{}: the scene reads no file", spec));
  const fs::path root = report.files.front().real.parent_path();
  for (const FileRef& f : report.files) {
    const std::string rel = f.real.lexically_relative(root).generic_string();
    if (!is_safe_relative_path(rel))
      throw SceneError(fmt::format("{}: '{}' lies outside the scene folder {}", spec, f.display, root.string()));
    b.files.emplace_back(rel, read_scene_file(f, opts.max_file_bytes));
    b.sources.push_back(f.real);
  }
  b.entry_path = report.files.front().real.filename().string();
  std::sort(b.files.begin(), b.files.end());
  return b;
}

std::string content_hash(const SceneBundleData& b) {
  if (!b.builtin.empty()) return sha256_hex("epr-builtin-v1\n" + b.builtin);
  std::vector<const std::pair<std::string, std::string>*> sorted;
  for (const auto& f : b.files) sorted.push_back(&f);
  std::sort(sorted.begin(), sorted.end(), [](auto* x, auto* y) { return x->first < y->first; });
  // The canonical serialisation, hashed as it is framed (not copied: a bundle may be large).
  Sha256 h;
  h.update(std::string("epr-scene-v1\n"));
  h.update_u64le(b.entry_path.size());
  h.update(b.entry_path);
  h.update_u64le(sorted.size());
  for (const auto* f : sorted) {
    h.update_u64le(f->first.size());
    h.update(f->first);
    h.update_u64le(f->second.size());
    h.update(f->second);
  }
  return h.hex();
}

std::string default_cache_root() {
  if (const char* d = std::getenv("EPR_CACHE_DIR"); d && *d) return d;
  if (const char* x = std::getenv("XDG_CACHE_HOME"); x && *x) return std::string(x) + "/eprfarm";
  if (const char* h = std::getenv("HOME"); h && *h) return std::string(h) + "/.cache/eprfarm";
  return (fs::temp_directory_path() / "eprfarm-cache").string();
}

namespace {

// The bundle's scene with its own lighting: a built-in generated, files written below the cache
// (once) and loaded from there.
Scene load_bundle_files(const SceneBundleData& b, const std::string& hash, const std::string& cache_root) {
  if (!b.builtin.empty()) return load_scene(b.builtin);
  // The client showed the warnings; here they stay at debug level.
  return load_scene(write_bundle_files(b, hash, cache_root));
}

}  // namespace

std::string write_bundle_files(const SceneBundleData& b, const std::string& hash, const std::string& cache_root) {
  if (!is_safe_relative_path(b.entry_path))
    throw SceneError(fmt::format("scene entry path '{}' is not a safe relative path", b.entry_path));
  const fs::path dir = fs::path(cache_root) / "scenes" / hash;
  const fs::path done = dir / ".complete";
  if (!fs::exists(done)) {
    // Write into a private folder and rename it into place, so a crash never leaves half a scene.
    const fs::path tmp = fs::path(cache_root) / "scenes" / fmt::format(".tmp-{}-{}", hash, ::getpid());
    fs::remove_all(tmp);
    for (const auto& [path, data] : b.files) {
      if (!is_safe_relative_path(path))
        throw SceneError(fmt::format("scene file path '{}' is not a safe relative path", path));
      fs::create_directories((tmp / path).parent_path());
      std::ofstream out(tmp / path, std::ios::binary);
      out.write(data.data(), std::streamsize(data.size()));
      if (!out) throw SceneError(fmt::format("cannot write scene cache file {}", (tmp / path).string()));
    }
    std::ofstream(tmp / ".complete") << hash << "\n";
    std::error_code ec;
    fs::rename(tmp, dir, ec);
    if (ec) fs::remove_all(tmp);  // another process won the race: its copy is identical
  }
  return (dir / b.entry_path).string();
}

Scene load_bundle(const SceneBundleData& b, const std::string& cache_root, const Lighting& job) {
  Scene s = load_bundle_files(b, content_hash(b), cache_root);
  s.lighting = job_lighting(s, job);
  // A file scene without light is refused (the check of raw submissions, which no client loaded first).
  if (b.builtin.empty())
    if (auto reason = unlit_reason(s)) throw SceneError(*reason);
  return s;
}

std::shared_ptr<const Scene> share_bundle_scene(const SceneBundleData& b, const std::string& hash,
                                                const std::string& cache_root, const Lighting& job) {
  std::shared_ptr<const Scene> s = shelved_scene(hash);
  if (!s) s = shelve_scene(hash, std::make_shared<const Scene>(load_bundle_files(b, hash, cache_root)));
  if (b.builtin.empty())
    if (auto reason = unlit_reason(*s, job_lighting(*s, job))) throw SceneError(*reason);
  return s;
}

}  // namespace epr
