#include "wire/scene_bundle.h"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include "common/scene_loader.h"

namespace epr {
namespace fs = std::filesystem;
namespace {

std::string read_file(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  if (!in) throw SceneError(fmt::format("{}: cannot read file", p.string()));
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// File names that an OBJ's `mtllib` or an MTL's `map_*` lines reference (last token of the line).
std::vector<std::string> referenced_files(const std::string& text, const std::vector<std::string>& keywords) {
  std::vector<std::string> out;
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    std::istringstream ls(line);
    std::string key;
    ls >> key;
    if (std::find(keywords.begin(), keywords.end(), key) == keywords.end()) continue;
    std::string rest, tok;
    while (ls >> tok) rest = tok;  // options such as -bm come before the name
    if (!rest.empty()) out.push_back(rest);
  }
  return out;
}

void put_u64(std::string& s, uint64_t v) {
  for (int i = 0; i < 8; ++i) s.push_back(char((v >> (8 * i)) & 0xff));
}

}  // namespace

size_t SceneBundleData::total_bytes() const {
  size_t n = 0;
  for (const auto& f : files) n += f.second.size();
  return n;
}

bool is_safe_relative_path(const std::string& path) {
  if (path.empty() || path.size() > 1024 || path[0] == '/' || path.find('\\') != std::string::npos) return false;
  std::istringstream in(path);
  std::string part;
  size_t parts = 0;
  while (std::getline(in, part, '/')) {
    if (part.empty() || part == "." || part == "..") return false;
    ++parts;
  }
  return parts > 0 && path.back() != '/';
}

SceneBundleData bundle_scene(const std::string& spec) {
  SceneBundleData b;
  if (spec.rfind("builtin:", 0) == 0) {
    b.builtin = spec;
    return b;
  }
  const fs::path entry = fs::weakly_canonical(spec);
  const fs::path root = entry.parent_path();
  std::set<std::string> seen;
  // Adds root/rel and whatever it references, depth first.
  std::function<void(const std::string&)> add = [&](const std::string& rel) {
    if (seen.count(rel)) return;
    const fs::path full = fs::weakly_canonical(root / rel);
    const std::string rel_norm = fs::relative(full, root).generic_string();
    if (!is_safe_relative_path(rel_norm))
      throw SceneError(fmt::format("{}: '{}' lies outside the scene folder {}", spec, rel, root.string()));
    if (seen.count(rel_norm)) return;
    seen.insert(rel_norm);
    const std::string data = read_file(full);
    b.files.emplace_back(rel_norm, data);
    const std::string ext = full.extension().string();
    const fs::path rel_dir = fs::path(rel_norm).parent_path();
    auto add_sibling = [&](const std::string& name) { add((rel_dir / name).generic_string()); };
    if (ext == ".obj" || ext == ".OBJ") {
      for (const auto& m : referenced_files(data, {"mtllib"})) add_sibling(m);
    } else if (ext == ".mtl" || ext == ".MTL") {
      for (const auto& t :
           referenced_files(data, {"map_Kd", "map_Ka", "map_Ks", "map_Ke", "map_d", "bump", "map_bump"}))
        if (fs::exists(root / rel_dir / t)) add_sibling(t);
    } else if (ext == ".json") {
      nlohmann::json j;
      try {
        j = nlohmann::json::parse(data);
      } catch (const std::exception&) {
        return;  // the loader reports the parse error with its line
      }
      if (j.is_object() && j.contains("obj") && j["obj"].is_string()) add_sibling(j["obj"].get<std::string>());
    }
  };
  add(entry.filename().string());
  b.entry_path = entry.filename().string();
  std::sort(b.files.begin(), b.files.end());
  return b;
}

std::string content_hash(const SceneBundleData& b) {
  if (!b.builtin.empty()) return sha256_hex("epr-builtin-v1\n" + b.builtin);
  std::vector<const std::pair<std::string, std::string>*> sorted;
  for (const auto& f : b.files) sorted.push_back(&f);
  std::sort(sorted.begin(), sorted.end(), [](auto* x, auto* y) { return x->first < y->first; });
  std::string s = "epr-scene-v1\n";
  put_u64(s, b.entry_path.size());
  s += b.entry_path;
  put_u64(s, sorted.size());
  for (const auto* f : sorted) {
    put_u64(s, f->first.size());
    s += f->first;
    put_u64(s, f->second.size());
    s += f->second;
  }
  return sha256_hex(s);
}

std::string default_cache_root() {
  if (const char* d = std::getenv("EPR_CACHE_DIR"); d && *d) return d;
  if (const char* x = std::getenv("XDG_CACHE_HOME"); x && *x) return std::string(x) + "/eprfarm";
  if (const char* h = std::getenv("HOME"); h && *h) return std::string(h) + "/.cache/eprfarm";
  return (fs::temp_directory_path() / "eprfarm-cache").string();
}

Scene load_bundle(const SceneBundleData& b, const std::string& cache_root) {
  if (!b.builtin.empty()) return load_scene(b.builtin);
  if (!is_safe_relative_path(b.entry_path))
    throw SceneError(fmt::format("scene entry path '{}' is not a safe relative path", b.entry_path));
  const std::string hash = content_hash(b);
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
  Scene s = load_scene((dir / b.entry_path).string());
  return s;
}

}  // namespace epr
