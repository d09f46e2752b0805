// The loader's entry points (scene_loader.h): a spec names a built-in scene, a scene JSON or an OBJ.
// The formats are read in common/scene_loader/: obj.cpp (with polygon.cpp), mtl.cpp, textures.cpp,
// scene_json.cpp, on top of text.cpp (lines, tokens, numbers, errors) and path_sandbox.cpp.
#include "common/scene_loader.h"

#include <algorithm>
#include <cctype>

#include "common/builtin_scenes.h"
#include "common/scene_loader/obj.h"
#include "common/scene_loader/path_sandbox.h"
#include "common/scene_loader/text.h"

namespace epr {
namespace {

bool ends_with_json(const std::string& s) {
  if (s.size() < 5) return false;
  std::string ext = s.substr(s.size() - 5);
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext == ".json";
}

}  // namespace

Scene load_obj(const std::string& obj_path, const LoadOptions& opts) {
  const std::filesystem::path real = loader::canonical_or_fail(obj_path, obj_path);
  Scene scene = loader::load_obj_inside({real, obj_path}, real.parent_path(), opts, nullptr);
  loader::validate_or_fail(scene, obj_path);
  return scene;
}

Scene load_scene(const std::string& spec, const LoadOptions& opts) {
  if (spec.rfind("builtin:", 0) == 0) return make_builtin_scene(parse_builtin_spec(spec.substr(8)), opts.max_triangles);
  if (ends_with_json(spec)) return load_scene_json(spec, opts);
  return load_obj(spec, opts);
}

}  // namespace epr
