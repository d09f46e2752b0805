#include "common/scene_loader.h"

#include <OpenImageIO/imageio.h>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <tiny_obj_loader.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <istream>
#include <limits>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <sstream>
#include <streambuf>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "common/builtin_scenes.h"
#include "common/image.h"
#include "common/log.h"

// How an OBJ is loaded. tinyobjloader parses, triangulates and reads the MTL files, but reports few
// line numbers and trusts its input (an out-of-range triangle index is used as is). So every file is
// first read by a strict line-by-line validator that knows the line of each statement, and
// tinyobjloader is then handed a sanitised copy that contains only statements the validator accepted,
// in a canonical form, with line numbers preserved:
//   - v / vt: finite numbers only (v: x y z, vt: u v), magnitudes bounded;
//   - f: corners as absolute 1-based "v" or "v/vt" indices, each checked against what is defined;
//   - mtllib: replaced by a key under which the already validated MTL text is served;
//   - MTL: newmtl, Kd, Ke, Ks, Ns and map_Kd (replaced by a key naming the loaded texture);
//   - everything else (normals, groups, lines, free-form geometry...) becomes an empty line.

namespace epr {
namespace {

namespace fs = std::filesystem;

// Larger coordinates would overflow float area and normal computations (cross products of edges).
constexpr double kMaxCoordinate = 1e8;
// tinyobjloader triangulates a polygon by ear clipping, in time quadratic in its corners: a single
// face of 20000 corners took minutes. Real models' n-gons (cylinder caps) stay far below this.
constexpr size_t kMaxFaceCorners = 1024;
// Scene JSON files are a few lines; this keeps a hostile one from costing much memory.
constexpr size_t kMaxJsonBytes = size_t(16) << 20;

std::shared_ptr<spdlog::logger> scene_log() { return logger("common"); }

[[noreturn]] void fail(const std::string& file, size_t line, const std::string& reason) {
  throw SceneError(fmt::format("{}:{}: {}", file, line, reason));
}

[[noreturn]] void fail_file(const std::string& file, const std::string& reason) {
  throw SceneError(fmt::format("{}: {}", file, reason));
}

/// Where a file is read from and how messages name it.
struct FileRef {
  fs::path real;        // canonical path that is opened
  std::string display;  // path as the user wrote it (joined to the referring file's folder)
};

/// Whole file, checked to be a regular file of at most max_bytes.
std::string read_file(const FileRef& f, size_t max_bytes) {
  std::error_code ec;
  const auto status = fs::status(f.real, ec);
  if (ec || !fs::exists(status)) fail_file(f.display, "cannot open: no such file");
  if (!fs::is_regular_file(status)) fail_file(f.display, "cannot open: not a regular file");
  const auto size = fs::file_size(f.real, ec);
  if (ec) fail_file(f.display, "cannot read its size: " + ec.message());
  if (size > max_bytes) fail_file(f.display, fmt::format("file has {} bytes, over the limit of {}", size, max_bytes));
  std::ifstream in(f.real, std::ios::binary);
  if (!in) fail_file(f.display, "cannot open for reading");
  std::string text(size_t(size), '\0');
  in.read(text.data(), std::streamsize(size));
  text.resize(size_t(in.gcount()));
  return text;
}

fs::path canonical_or_fail(const fs::path& p, const std::string& display) {
  std::error_code ec;
  fs::path c = fs::weakly_canonical(fs::absolute(p, ec), ec);
  if (ec) fail_file(display, "cannot resolve path: " + ec.message());
  return c;
}

bool is_inside(const fs::path& root, const fs::path& p) {
  auto r = root.begin(), q = p.begin();
  for (; r != root.end(); ++r, ++q) {
    if (r->empty()) continue;  // trailing separator of the root
    if (q == p.end() || *r != *q) return false;
  }
  return true;
}

/// Resolves `name` written in `file` at `line` relative to `dir`, and checks that it stays inside
/// `root` after resolving symlinks.
FileRef resolve_inside(const fs::path& root, const fs::path& dir, const std::string& display_dir,
                       const std::string& name, const std::string& file, size_t line, const char* what) {
  if (name.empty()) fail(file, line, fmt::format("empty {} path", what));
  if (name.find('\0') != std::string::npos) fail(file, line, fmt::format("{} path contains a NUL byte", what));
  const fs::path rel(name);
  if (rel.is_absolute() || rel.has_root_directory() || rel.has_root_name())
    fail(file, line,
         fmt::format("{} '{}' is an absolute path; scene files must name files inside the scene folder", what, name));
  std::error_code ec;
  const fs::path real = fs::weakly_canonical(dir / rel, ec);
  if (ec) fail(file, line, fmt::format("cannot resolve {} '{}': {}", what, name, ec.message()));
  if (!is_inside(root, real)) fail(file, line, fmt::format("{} '{}' leaves the scene folder", what, name));
  const std::string display = display_dir.empty() ? name : (fs::path(display_dir) / rel).lexically_normal().string();
  return {real, display};
}

// ---------------------------------------------------------------------------------------------------
// Lines, tokens and numbers
// ---------------------------------------------------------------------------------------------------

/// Splits text into lines as tinyobjloader does: "\n", "\r\n" and a lone "\r" each end a line.
class LineReader {
 public:
  explicit LineReader(std::string_view text) : text_(text) {}

  bool next(std::string_view* line) {
    if (pos_ >= text_.size()) return false;
    size_t end = pos_;
    while (end < text_.size() && text_[end] != '\n' && text_[end] != '\r') ++end;
    *line = text_.substr(pos_, end - pos_);
    pos_ = end;
    if (pos_ < text_.size()) {
      if (text_[pos_] == '\r' && pos_ + 1 < text_.size() && text_[pos_ + 1] == '\n') ++pos_;
      ++pos_;
    }
    ++number_;
    return true;
  }
  size_t number() const { return number_; }

 private:
  std::string_view text_;
  size_t pos_ = 0;
  size_t number_ = 0;
};

bool is_space(char c) { return c == ' ' || c == '\t'; }

/// Removes a comment (a token starting with '#') and surrounding blanks.
std::string_view strip_comment(std::string_view line) {
  for (size_t i = 0; i < line.size(); ++i)
    if (line[i] == '#' && (i == 0 || is_space(line[i - 1]))) {
      line = line.substr(0, i);
      break;
    }
  while (!line.empty() && is_space(line.front())) line.remove_prefix(1);
  while (!line.empty() && is_space(line.back())) line.remove_suffix(1);
  return line;
}

/// Tokens separated by blanks (spaces and tabs, as tinyobjloader has it).
void tokenize(std::string_view line, std::vector<std::string_view>* tokens) {
  tokens->clear();
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && is_space(line[i])) ++i;
    const size_t start = i;
    while (i < line.size() && !is_space(line[i])) ++i;
    if (i > start) tokens->push_back(line.substr(start, i - start));
  }
}

/// The statement's argument text: the line after its keyword, without comment and blanks.
std::string_view rest_after_keyword(std::string_view stripped, std::string_view keyword) {
  std::string_view rest = stripped.substr(keyword.size());
  while (!rest.empty() && is_space(rest.front())) rest.remove_prefix(1);
  return rest;
}

std::string quote_token(std::string_view token) {
  constexpr size_t kMax = 40;
  std::string s(token.substr(0, kMax));
  for (char& c : s)
    if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) c = '?';
  return "'" + s + (token.size() > kMax ? "...'" : "'");
}

/// A decimal number that must be finite and at most `limit` in magnitude; failures raise file:line.
float parse_real(std::string_view tok, double limit, const std::string& file, size_t line, const char* what) {
  std::string_view s = tok;
  if (s.size() > 1 && s[0] == '+' && s[1] != '-' && s[1] != '+') s.remove_prefix(1);
  double v = 0;
  const char* end = s.data() + s.size();
  const auto [ptr, ec] = std::from_chars(s.data(), end, v);
  if (ec == std::errc::result_out_of_range)
    fail(file, line, fmt::format("{} {} is out of range", what, quote_token(tok)));
  if (ec != std::errc() || ptr != end || s.empty())
    fail(file, line, fmt::format("bad number {} for {}", quote_token(tok), what));
  if (!std::isfinite(v)) fail(file, line, fmt::format("{} {} is not finite", what, quote_token(tok)));
  if (std::abs(v) > limit)
    fail(file, line, fmt::format("{} {} exceeds the magnitude limit {:g}", what, quote_token(tok), limit));
  return float(v);
}

/// Splits an mtllib argument like tinyobjloader: blanks separate names, a backslash escapes the next
/// character.
std::vector<std::string> split_escaped(std::string_view s) {
  std::vector<std::string> out;
  std::string cur;
  bool escaping = false;
  for (char c : s) {
    if (escaping) {
      cur += c;
      escaping = false;
    } else if (c == '\\') {
      escaping = true;
    } else if (is_space(c)) {
      if (!cur.empty()) out.push_back(std::move(cur));
      cur.clear();
    } else {
      cur += c;
    }
  }
  if (!cur.empty()) out.push_back(std::move(cur));
  return out;
}

std::string format_real(float v) { return fmt::format("{}", v); }

// ---------------------------------------------------------------------------------------------------
// Textures
// ---------------------------------------------------------------------------------------------------

/// State shared by the OBJ, its MTL files and textures.
struct ObjContext {
  ObjContext(const LoadOptions& o, fs::path r) : opts(o), root(std::move(r)) {}

  const LoadOptions& opts;
  fs::path root;  // canonical: nothing outside it is read
  std::vector<Texture> textures;
  std::map<fs::path, int> texture_of_path;
  std::map<fs::path, std::string> mtl_cache;                  // sanitised MTL text per file
  std::map<std::string, std::string> mtl_key;                 // mtllib key -> sanitised text of the line's files
  std::map<std::vector<fs::path>, std::string> key_of_files;  // one key per distinct list of files
  size_t mtl_bytes = 0;                                       // total of mtl_key's texts
  size_t texture_pixels = 0;                                  // total of all textures
  std::set<std::string> defined_materials;                    // names from the MTL files read so far
};

Texture to_texture(const Image& img, const std::string& name, const std::string& file, size_t line, size_t* clamped) {
  Texture t;
  t.path = name;
  t.width = img.width;
  t.height = img.height;
  t.rgb.resize(size_t(img.width) * size_t(img.height) * 3);
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      const Vec3 c = img.rgb(x, y);
      if (!is_finite(c)) fail(file, line, fmt::format("texture '{}' has non-finite texels", name));
      float* out = &t.rgb[(size_t(y) * size_t(img.width) + size_t(x)) * 3];
      for (int k = 0; k < 3; ++k) {
        const float v = std::clamp(c[k], 0.f, 1.f);
        if (v != c[k]) ++*clamped;
        out[k] = v;
      }
    }
  return t;
}

/// Loads the texture `name` (from map_Kd in `file` at `line`), once per file; returns its index.
int load_texture(ObjContext& ctx, const std::string& name, const fs::path& dir, const std::string& display_dir,
                 const std::string& file, size_t line) {
  std::string portable = name;
  std::replace(portable.begin(), portable.end(), '\\', '/');  // textures named on Windows
  const FileRef ref = resolve_inside(ctx.root, dir, display_dir, portable, file, line, "texture");
  if (auto it = ctx.texture_of_path.find(ref.real); it != ctx.texture_of_path.end()) return it->second;

  std::error_code ec;
  if (!fs::is_regular_file(ref.real, ec)) fail(file, line, fmt::format("texture '{}' does not exist", name));
  const auto bytes = fs::file_size(ref.real, ec);
  if (ec || bytes > ctx.opts.max_file_bytes)
    fail(file, line,
         fmt::format("texture '{}' is over the file size limit of {} bytes", name, ctx.opts.max_file_bytes));
  {
    // Check the size before read_image allocates it.
    auto in = OIIO::ImageInput::open(ref.real.string());
    if (!in) fail(file, line, fmt::format("cannot read texture '{}': {}", name, OIIO::geterror()));
    const OIIO::ImageSpec& spec = in->spec();
    const double pixels = double(std::max(spec.width, 0)) * double(std::max(spec.height, 0));
    if (pixels + double(ctx.texture_pixels) > double(ctx.opts.max_texture_pixels))
      fail(file, line,
           fmt::format("texture '{}' has {} x {} pixels: the scene's textures exceed the limit of {} pixels", name,
                       spec.width, spec.height, ctx.opts.max_texture_pixels));
    if (spec.nchannels < 1 || spec.nchannels > 16)
      fail(file, line, fmt::format("texture '{}' has {} channels", name, spec.nchannels));
    in->close();
  }
  Image img;
  try {
    img = read_image(ref.real.string());
  } catch (const std::exception& e) {
    fail(file, line, fmt::format("cannot read texture '{}': {}", name, e.what()));
  }
  if (img.width <= 0 || img.height <= 0 || img.channels <= 0 ||
      img.data.size() != size_t(img.width) * size_t(img.height) * size_t(img.channels))
    fail(file, line, fmt::format("texture '{}' is empty or malformed", name));
  size_t clamped = 0;
  ctx.texture_pixels += size_t(img.width) * size_t(img.height);
  ctx.textures.push_back(to_texture(img, name, file, line, &clamped));
  if (clamped > 0)
    scene_log()->warn("{}:{}: texture '{}': {} values outside [0, 1] clamped (it is a diffuse albedo)", file, line,
                      name, clamped);
  const int index = int(ctx.textures.size() - 1);
  ctx.texture_of_path.emplace(ref.real, index);
  return index;
}

// ---------------------------------------------------------------------------------------------------
// MTL
// ---------------------------------------------------------------------------------------------------

/// Validates an MTL file, loads its textures and returns the sanitised text for tinyobjloader.
std::string scan_mtl(ObjContext& ctx, const FileRef& mtl) {
  if (auto it = ctx.mtl_cache.find(mtl.real); it != ctx.mtl_cache.end()) return it->second;
  const std::string text = read_file(mtl, ctx.opts.max_file_bytes);
  const fs::path dir = mtl.real.parent_path();
  const std::string display_dir = fs::path(mtl.display).parent_path().string();
  const std::string& file = mtl.display;

  std::string out;
  out.reserve(text.size() / 2);
  std::vector<std::string_view> tok;
  std::string_view raw;
  LineReader lines(text);
  std::string current;  // material being defined
  std::set<std::string> names_here;
  while (lines.next(&raw)) {
    const size_t ln = lines.number();
    if (raw.find('\0') != std::string_view::npos) fail(file, ln, "NUL byte in a text file");
    const std::string_view line = strip_comment(raw);
    tokenize(line, &tok);
    if (tok.empty()) {
      out += '\n';
      continue;
    }
    const std::string_view key = tok[0];
    if (key == "newmtl") {
      if (tok.size() < 2) fail(file, ln, "newmtl without a material name");
      current = std::string(tok[1]);
      if (!names_here.insert(current).second || ctx.defined_materials.count(current))
        scene_log()->warn("{}:{}: material '{}' is defined again; the first definition is used", file, ln, current);
      out += "newmtl " + current + '\n';
    } else if (key == "Kd" || key == "Ke" || key == "Ks") {
      if (current.empty()) fail(file, ln, fmt::format("{} before any newmtl", key));
      if (tok.size() == 2 || tok.size() == 4) {
        float v[3];
        for (size_t k = 0; k < 3; ++k)
          v[k] = parse_real(tok[std::min(k + 1, tok.size() - 1)], 1e6, file, ln, "colour value");
        out += fmt::format("{} {} {} {}\n", key, format_real(v[0]), format_real(v[1]), format_real(v[2]));
      } else {
        fail(file, ln,
             fmt::format("{} needs 1 or 3 numbers (spectral and xyz forms are not supported), got {}", key,
                         tok.size() - 1));
      }
    } else if (key == "Ns") {
      if (current.empty()) fail(file, ln, "Ns before any newmtl");
      if (tok.size() != 2) fail(file, ln, fmt::format("Ns needs 1 number, got {}", tok.size() - 1));
      out += "Ns " + format_real(parse_real(tok[1], 1e6, file, ln, "Ns exponent")) + '\n';
    } else if (key == "map_Kd") {
      if (current.empty()) fail(file, ln, "map_Kd before any newmtl");
      const std::string args(rest_after_keyword(line, key));
      std::string texname;
      tinyobj::texture_option_t opt{};
      if (!tinyobj::ParseTextureNameAndOption(&texname, &opt, args.c_str()) || strip_comment(texname).empty())
        fail(file, ln, "map_Kd without a texture file name");
      texname = std::string(strip_comment(texname));
      const int index = load_texture(ctx, texname, dir, display_dir, file, ln);
      out += fmt::format("map_Kd tex{}\n", index);
    } else {
      out += '\n';  // Ka, Ni, d, illum, other maps...: not part of the material model
    }
  }
  ctx.defined_materials.insert(names_here.begin(), names_here.end());
  ctx.mtl_cache.emplace(mtl.real, out);
  return out;
}

/// Serves the sanitised MTL texts to tinyobjloader by key.
class KeyedMtlReader final : public tinyobj::MaterialReader {
 public:
  explicit KeyedMtlReader(const std::map<std::string, std::string>& texts) : texts_(texts) {}
  bool operator()(const std::string& key, std::vector<tinyobj::material_t>* materials,
                  std::map<std::string, int>* material_map, std::string* warn, std::string* err) override {
    const auto it = texts_.find(key);
    if (it == texts_.end()) return false;
    std::istringstream in(it->second);
    tinyobj::LoadMtl(material_map, materials, &in, warn, err);
    return true;
  }

 private:
  const std::map<std::string, std::string>& texts_;
};

/// A read-only istream over a string, without copying it.
class MemoryBuffer : public std::streambuf {
 public:
  explicit MemoryBuffer(const std::string& s) {
    char* p = const_cast<char*>(s.data());
    setg(p, p, p + s.size());
  }
};

// ---------------------------------------------------------------------------------------------------
// OBJ
// ---------------------------------------------------------------------------------------------------

/// Parses one face corner ("v", "v/vt", "v//vn", "v/vt/vn") into absolute 0-based indices (vt -1 if
/// absent); returns the reason if malformed.
std::optional<std::string> parse_corner(std::string_view tok, size_t nv, size_t nvt, size_t nvn, uint32_t* v,
                                        int64_t* vt) {
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
  int64_t vi = 0;
  if (auto e = resolve(parts[0], nv, "vertex", &vi)) return e;
  *v = uint32_t(vi);
  *vt = -1;
  if (count >= 2 && !parts[1].empty()) {  // "v//vn" has no texture coordinate
    if (auto e = resolve(parts[1], nvt, "texture coordinate", vt)) return e;
  }
  if (count == 3) {
    int64_t ni = 0;
    if (auto e = resolve(parts[2], nvn, "normal", &ni)) return e;
  }
  return std::nullopt;
}

struct ObjScan {
  std::string sanitized;
  size_t lines = 0;
  size_t faces = 0;
  bool any_uv = false;
  size_t first_degenerate_line = 0;  // first triangle face of zero area (0: none), for messages
};

/// Validates the OBJ line by line (reading its MTL files and textures on the way) and returns the
/// sanitised text for tinyobjloader.
ObjScan scan_obj(ObjContext& ctx, const FileRef& obj, const std::string& text) {
  const std::string& file = obj.display;
  const fs::path dir = obj.real.parent_path();
  const std::string display_dir = fs::path(obj.display).parent_path().string();
  constexpr size_t kMaxVertices = size_t(std::numeric_limits<int32_t>::max()) - 1;  // tinyobjloader: int

  ObjScan scan;
  scan.sanitized.reserve(text.size());
  std::string& out = scan.sanitized;
  size_t nv = 0, nvt = 0, nvn = 0, triangles = 0;
  std::vector<Vec3> positions;  // as parsed: the zero-area test of triangle faces names their line
  std::vector<std::string_view> tok;
  std::set<std::string, std::less<>> warned_keywords;
  std::string_view raw;
  LineReader lines(text);
  while (lines.next(&raw)) {
    const size_t ln = lines.number();
    if (raw.find('\0') != std::string_view::npos) fail(file, ln, "NUL byte in a text file");
    const std::string_view line = strip_comment(raw);
    tokenize(line, &tok);
    if (tok.empty()) {
      out += '\n';
      continue;
    }
    const std::string_view key = tok[0];
    if (key == "v") {
      if (tok.size() < 4 || tok.size() > 8)
        fail(file, ln, fmt::format("vertex needs 3 coordinates (x y z [w] [r g b]), got {}", tok.size() - 1));
      float p[3];
      for (size_t k = 0; k < 3; ++k) p[k] = parse_real(tok[k + 1], kMaxCoordinate, file, ln, "coordinate");
      for (size_t k = 4; k < tok.size(); ++k) parse_real(tok[k], 1e30, file, ln, "vertex weight or colour");
      if (++nv > kMaxVertices) fail(file, ln, "too many vertices");
      positions.push_back({p[0], p[1], p[2]});
      out += fmt::format("v {} {} {}\n", format_real(p[0]), format_real(p[1]), format_real(p[2]));
    } else if (key == "vt") {
      if (tok.size() < 2 || tok.size() > 4)
        fail(file, ln, fmt::format("texture coordinate needs 1 to 3 numbers, got {}", tok.size() - 1));
      float uv[2] = {0, 0};
      for (size_t k = 1; k < tok.size(); ++k) {
        const float x = parse_real(tok[k], kMaxCoordinate, file, ln, "texture coordinate");
        if (k <= 2) uv[k - 1] = x;
      }
      if (++nvt > kMaxVertices) fail(file, ln, "too many texture coordinates");
      out += fmt::format("vt {} {}\n", format_real(uv[0]), format_real(uv[1]));
    } else if (key == "vn") {
      if (tok.size() != 4) fail(file, ln, fmt::format("normal needs 3 numbers, got {}", tok.size() - 1));
      for (size_t k = 1; k < 4; ++k) parse_real(tok[k], 1e30, file, ln, "normal component");
      if (++nvn > kMaxVertices) fail(file, ln, "too many normals");
      out += '\n';  // normals are not used: faces are flat
    } else if (key == "f") {
      if (tok.size() < 4) fail(file, ln, fmt::format("face needs at least 3 vertices, got {}", tok.size() - 1));
      if (tok.size() - 1 > kMaxFaceCorners)
        fail(file, ln,
             fmt::format("face has {} vertices, more than the {} supported", tok.size() - 1, kMaxFaceCorners));
      triangles += tok.size() - 3;
      if (triangles > ctx.opts.max_triangles)
        fail(file, ln, fmt::format("more than {} triangles (the limit)", ctx.opts.max_triangles));
      out += 'f';
      uint32_t corner[3] = {0, 0, 0};
      for (size_t k = 1; k < tok.size(); ++k) {
        uint32_t v = 0;
        int64_t vt = -1;
        if (auto err = parse_corner(tok[k], nv, nvt, nvn, &v, &vt)) fail(file, ln, *err);
        if (k <= 3) corner[k - 1] = v;
        if (vt >= 0) {
          out += fmt::format(" {}/{}", v + 1, vt + 1);
          scan.any_uv = true;
        } else {
          out += fmt::format(" {}", v + 1);
        }
      }
      out += '\n';
      ++scan.faces;
      if (tok.size() == 4 && scan.first_degenerate_line == 0) {  // load_obj_inside's zero-area test
        const Vec3 &a = positions[corner[0]], &b = positions[corner[1]], &c = positions[corner[2]];
        if (!(length(cross(b - a, c - a)) > 0.f)) scan.first_degenerate_line = ln;
      }
    } else if (key == "usemtl") {
      if (tok.size() < 2) fail(file, ln, "usemtl without a material name");
      const std::string name(tok[1]);
      if (!ctx.defined_materials.count(name))
        scene_log()->warn("{}:{}: material '{}' is not defined by an earlier mtllib; using the default grey", file, ln,
                          name);
      out += "usemtl " + name + '\n';
    } else if (key == "mtllib") {
      const auto names = split_escaped(rest_after_keyword(line, key));
      if (names.empty()) fail(file, ln, "mtllib names no file");
      std::vector<FileRef> mtls;
      std::vector<fs::path> reals;
      for (const std::string& name : names) {
        mtls.push_back(resolve_inside(ctx.root, dir, display_dir, name, file, ln, "mtllib"));
        reals.push_back(mtls.back().real);
        std::error_code ec;
        if (!fs::is_regular_file(reals.back(), ec)) fail(file, ln, fmt::format("mtllib '{}' does not exist", name));
      }
      auto [it, added] = ctx.key_of_files.emplace(reals, fmt::format("mtl{}", ctx.key_of_files.size()));
      if (added) {
        std::string combined;
        for (const FileRef& mtl : mtls) combined += scan_mtl(ctx, mtl) + '\n';
        ctx.mtl_bytes += combined.size();
        if (ctx.mtl_bytes > ctx.opts.max_file_bytes)
          fail(file, ln, fmt::format("material libraries exceed {} bytes in total", ctx.opts.max_file_bytes));
        ctx.mtl_key.emplace(it->second, std::move(combined));
      }
      out += "mtllib " + it->second + '\n';
    } else {
      static const std::set<std::string, std::less<>> kIgnored = {"g", "o", "s", "l", "p", "vp"};
      if (!kIgnored.count(key) && warned_keywords.insert(std::string(key)).second)
        scene_log()->warn("{}:{}: unsupported statement {} ignored", file, ln, quote_token(key));
      out += '\n';
    }
  }
  scan.lines = lines.number();
  if (scan.faces == 0) fail_file(file, "no faces");
  return scan;
}

Vec3 clamped_colour(const float c[3], float hi, const std::string& file, const std::string& material,
                    const char* what) {
  Vec3 v(c[0], c[1], c[2]);
  const Vec3 clamped(std::clamp(v.x, 0.f, hi), std::clamp(v.y, 0.f, hi), std::clamp(v.z, 0.f, hi));
  if (!(clamped == v))
    scene_log()->warn("{}: material '{}': {} ({}, {}, {}) clamped to [0, {}]", file, material, what, v.x, v.y, v.z, hi);
  return clamped;
}

/// MTL values that the Lambertian model ignores but a JSON "glossy" override starts from.
struct GlossyDefaults {
  Vec3 ks{0.f};
  float exponent = Material{}.exponent;
};

Scene load_obj_inside(const FileRef& obj, const fs::path& root, const LoadOptions& opts,
                      std::vector<GlossyDefaults>* glossy) {
  const std::string text = read_file(obj, opts.max_file_bytes);
  ObjContext ctx(opts, root);
  const ObjScan scan = scan_obj(ctx, obj, text);
  const std::string& file = obj.display;

  tinyobj::attrib_t attrib;
  std::vector<tinyobj::shape_t> shapes;
  std::vector<tinyobj::material_t> materials;
  std::string warn, err;
  KeyedMtlReader reader(ctx.mtl_key);
  MemoryBuffer buffer(scan.sanitized);
  std::istream in(&buffer);
  const bool ok = tinyobj::LoadObj(&attrib, &shapes, &materials, &warn, &err, &in, &reader, /*triangulate=*/true,
                                   /*default_vcols_fallback=*/false);
  if (!warn.empty()) scene_log()->debug("{}: tinyobjloader: {}", file, warn);
  if (!ok) fail_file(file, "tinyobjloader: " + err);

  Scene scene;
  scene.name = obj.display;
  const size_t nv = attrib.vertices.size() / 3;
  scene.positions.resize(nv);
  for (size_t i = 0; i < nv; ++i) {
    scene.positions[i] = {attrib.vertices[3 * i], attrib.vertices[3 * i + 1], attrib.vertices[3 * i + 2]};
    if (!is_finite(scene.positions[i])) fail_file(file, fmt::format("vertex {} is not finite", i + 1));
  }

  for (const tinyobj::material_t& m : materials) {
    Material mat;
    mat.name = m.name;
    mat.kd = clamped_colour(m.diffuse, 1.f, file, m.name, "Kd");
    mat.ke = clamped_colour(m.emission, 1e6f, file, m.name, "Ke");
    if (m.diffuse_texname.rfind("tex", 0) == 0) {
      int index = -1;
      const std::string_view digits = std::string_view(m.diffuse_texname).substr(3);
      std::from_chars(digits.data(), digits.data() + digits.size(), index);
      if (index >= 0 && index < int(ctx.textures.size())) mat.kd_texture = index;
    }
    add_material(scene, std::move(mat));
    if (glossy)
      glossy->push_back({clamped_colour(m.specular, 1.f, file, m.name, "Ks"),
                         m.shininess > 0 && std::isfinite(m.shininess) ? float(m.shininess) : Material{}.exponent});
  }
  scene.textures = std::move(ctx.textures);

  int default_material = -1;
  size_t degenerate = 0;
  bool uses_texture = false, textured_without_uv = false;
  std::vector<std::array<Vec2, 3>> uvs;
  const size_t nvt = attrib.texcoords.size() / 2;
  for (const tinyobj::shape_t& shape : shapes) {
    const auto& idx = shape.mesh.indices;
    const size_t tris = std::min(idx.size() / 3, shape.mesh.material_ids.size());
    for (size_t t = 0; t < tris; ++t) {
      std::array<uint32_t, 3> tri;
      std::array<Vec2, 3> uv{};
      bool has_uv = true;
      for (int k = 0; k < 3; ++k) {
        const tinyobj::index_t& c = idx[3 * t + size_t(k)];
        if (c.vertex_index < 0 || size_t(c.vertex_index) >= nv)
          fail_file(file, fmt::format("triangle {} has a vertex index out of range", t));  // validated; defensive
        tri[size_t(k)] = uint32_t(c.vertex_index);
        if (c.texcoord_index >= 0 && size_t(c.texcoord_index) < nvt)
          uv[size_t(k)] = {attrib.texcoords[2 * size_t(c.texcoord_index)],
                           attrib.texcoords[2 * size_t(c.texcoord_index) + 1]};
        else
          has_uv = false;
      }
      const Vec3 &a = scene.positions[tri[0]], &b = scene.positions[tri[1]], &c = scene.positions[tri[2]];
      if (!(length(cross(b - a, c - a)) > 0.f)) {
        ++degenerate;
        continue;
      }
      int mat = shape.mesh.material_ids[t];
      if (mat < 0 || size_t(mat) >= scene.materials.size()) {
        if (default_material < 0) {
          Material grey;
          grey.name = "default";
          grey.kd = Vec3(0.8f);
          default_material = int(add_material(scene, grey));
          if (glossy) glossy->push_back({});
        }
        mat = default_material;
      }
      if (scene.materials[size_t(mat)].kd_texture >= 0) {
        uses_texture = true;
        textured_without_uv |= !has_uv;
      }
      scene.triangles.push_back(tri);
      scene.material_of.push_back(uint32_t(mat));
      uvs.push_back(uv);
    }
  }
  // Zero-area triangles are dropped, not fatal (exporters leave slivers behind); a scene of nothing but
  // them is an error. Both messages name the first zero-area triangle face when there is one (a
  // polygon's triangles are only known after triangulation).
  const std::string where =
      scan.first_degenerate_line > 0 ? fmt::format("{}:{}", file, scan.first_degenerate_line) : file;
  const std::string first = scan.first_degenerate_line > 0 ? " (the first on this line)" : "";
  if (scene.triangles.empty())
    throw SceneError(fmt::format("{}: all {} triangles are degenerate (zero area){}", where, degenerate, first));
  if (degenerate > 0) scene_log()->warn("{}: dropped {} degenerate (zero-area) triangles{}", where, degenerate, first);
  if (uses_texture) scene.uvs = std::move(uvs);
  if (textured_without_uv)
    scene_log()->warn("{}: some textured faces have no texture coordinates; they use texel (0, 0)", file);
  return scene;
}

void validate_or_fail(const Scene& scene, const std::string& file) {
  try {
    scene.validate();
  } catch (const std::exception& e) {
    fail_file(file, e.what());
  }
}

// ---------------------------------------------------------------------------------------------------
// Scene JSON
// ---------------------------------------------------------------------------------------------------

std::string pointer_token(std::string_view s) {
  std::string out;
  for (char c : s) {
    if (c == '~')
      out += "~0";
    else if (c == '/')
      out += "~1";
    else
      out += c;
  }
  return out;
}

/// The line each value of an (already parsed) JSON text starts on, by JSON pointer ("/camera/fov"):
/// nlohmann::json keeps no source positions.
class JsonLines {
 public:
  explicit JsonLines(std::string_view text) {
    struct Frame {
      bool object;
      std::string path;
      std::string key;
      size_t index = 0;
      bool expect_key = true;
    };
    // Only the first levels get pointers (the schema is 4 deep): deeper nesting would make the paths
    // grow with the square of the depth.
    constexpr size_t kMaxDepth = 8;
    std::vector<Frame> stack;
    size_t line = 1;
    bool in_scalar = false;
    auto value_path = [&]() -> std::string {
      if (stack.empty()) return "";
      const Frame& f = stack.back();
      if (stack.size() > kMaxDepth) return f.path;
      return f.path + "/" + (f.object ? pointer_token(f.key) : std::to_string(f.index));
    };
    auto record = [&](const std::string& path) {
      if (stack.size() <= kMaxDepth) lines_[path] = line;
    };
    for (size_t i = 0; i < text.size(); ++i) {
      const char c = text[i];
      const bool scalar_char = std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '+' || c == '.';
      if (scalar_char) {
        if (!in_scalar) record(value_path());
        in_scalar = true;
        continue;
      }
      in_scalar = false;
      if (c == '\n') {
        ++line;
      } else if (c == '/' && i + 1 < text.size() && text[i + 1] == '/') {
        while (i + 1 < text.size() && text[i + 1] != '\n') ++i;
      } else if (c == '/' && i + 1 < text.size() && text[i + 1] == '*') {
        i += 2;
        while (i + 1 < text.size() && !(text[i] == '*' && text[i + 1] == '/')) line += text[i++] == '\n';
        ++i;
      } else if (c == '"') {
        size_t j = i + 1;
        while (j < text.size() && text[j] != '"') j += text[j] == '\\' ? 2 : 1;
        const std::string_view raw = text.substr(i, std::min(j, text.size() - 1) - i + 1);
        if (!stack.empty() && stack.back().object && stack.back().expect_key) {
          try {
            stack.back().key = nlohmann::json::parse(raw).get<std::string>();
          } catch (const std::exception&) {
            stack.back().key = std::string(raw);
          }
          stack.back().expect_key = false;
        } else {
          record(value_path());
        }
        i = j;
      } else if (c == ',') {
        if (!stack.empty()) {
          if (stack.back().object)
            stack.back().expect_key = true;
          else
            ++stack.back().index;
        }
      } else if (c == '{' || c == '[') {
        const std::string path = value_path();
        record(path);
        stack.push_back({c == '{', path, "", 0, true});
      } else if ((c == '}' || c == ']') && !stack.empty()) {
        stack.pop_back();
      }
    }
  }

  /// Line of the value at `pointer`, or of its nearest recorded ancestor.
  size_t line(std::string pointer) const {
    for (;;) {
      if (auto it = lines_.find(pointer); it != lines_.end()) return it->second;
      if (pointer.empty()) return 1;
      pointer.resize(pointer.rfind('/'));
    }
  }

 private:
  std::unordered_map<std::string, size_t> lines_;
};

class JsonSceneReader {
 public:
  JsonSceneReader(const std::string& path, const LoadOptions& opts) : path_(path), opts_(opts) {}

  Scene read() {
    const FileRef self{canonical_or_fail(path_, path_), path_};
    const std::string text = read_file(self, std::min(opts_.max_file_bytes, kMaxJsonBytes));
    nlohmann::json doc;
    try {
      doc = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/true, /*ignore_comments=*/true);
    } catch (const nlohmann::json::parse_error& e) {
      fail(path_, line_at_byte(text, e.byte), "invalid JSON: " + json_reason(e));
    } catch (const nlohmann::json::exception& e) {
      // Number overflow ("number overflow parsing '1e999'") carries no position: find the number.
      const std::string what = e.what();
      const size_t open = what.find('\''), close = what.rfind('\'');
      size_t at = 0;
      if (open != std::string::npos && close > open + 1) at = text.find(what.substr(open + 1, close - open - 1));
      fail(path_, at == std::string::npos ? 1 : line_at_byte(text, at + 1), "invalid JSON: " + json_reason(e));
    }
    lines_ = std::make_unique<JsonLines>(text);
    if (!doc.is_object()) error("", "a scene file must be a JSON object");
    check_keys(doc, "", {"obj", "builtin", "tessellation", "camera", "materials"});

    Scene scene;
    std::vector<GlossyDefaults> glossy;
    const bool has_obj = doc.contains("obj"), has_builtin = doc.contains("builtin");
    if (has_obj == has_builtin) error("", "give exactly one of \"obj\" and \"builtin\"");
    if (has_obj) {
      if (doc.contains("tessellation")) error("/tessellation", "\"tessellation\" applies to built-in scenes only");
      const std::string obj = string_at(doc, "/obj");
      const fs::path root = self.real.parent_path();
      const std::string display_dir = fs::path(path_).parent_path().string();
      const FileRef ref = resolve_inside(root, root, display_dir, obj, path_, line("/obj"), "obj");
      std::error_code ec;
      if (!fs::is_regular_file(ref.real, ec)) error("/obj", fmt::format("obj file '{}' does not exist", obj));
      scene = load_obj_inside(ref, root, opts_, &glossy);
    } else {
      BuiltinSpec spec;
      try {
        spec = parse_builtin_spec(string_at(doc, "/builtin"));
        if (doc.contains("tessellation")) {
          const auto& t = doc["tessellation"];
          if (!t.is_number_integer()) error("/tessellation", "\"tessellation\" must be an integer");
          if (spec.tessellation != 1) error("/tessellation", "tessellation given both here and in \"builtin\"");
          spec.tessellation = int(std::clamp<int64_t>(t.get<int64_t>(), -1, 1 << 20));
        }
        scene = make_builtin_scene(spec, opts_.max_triangles);
      } catch (const SceneError& e) {
        if (std::string_view(e.what()).rfind(path_ + ":", 0) == 0) throw;
        fail(path_, line(doc.contains("tessellation") ? "/tessellation" : "/builtin"), e.what());
      }
      for (const Material& m : scene.materials) glossy.push_back({m.ks, m.exponent});
    }
    if (doc.contains("camera")) apply_camera(doc["camera"], &scene.camera);
    if (doc.contains("materials")) apply_materials(doc["materials"], glossy, &scene);
    scene.name = path_;
    validate_or_fail(scene, path_);
    return scene;
  }

 private:
  /// nlohmann's message without its "[json.exception.parse_error.101] " tag.
  static std::string json_reason(const nlohmann::json::exception& e) {
    std::string what = e.what();
    if (const size_t p = what.find("] "); what.rfind("[json.exception", 0) == 0 && p != std::string::npos)
      what = what.substr(p + 2);
    return what;
  }

  static size_t line_at_byte(const std::string& text, size_t byte) {
    const size_t end = std::min(byte > 0 ? byte - 1 : 0, text.size());
    return 1 + size_t(std::count(text.begin(), text.begin() + std::ptrdiff_t(end), '\n'));
  }

  size_t line(const std::string& pointer) const { return lines_->line(pointer); }

  [[noreturn]] void error(const std::string& pointer, const std::string& reason) const {
    fail(path_, line(pointer), reason);
  }

  void check_keys(const nlohmann::json& obj, const std::string& pointer, std::initializer_list<const char*> known) {
    for (const auto& item : obj.items()) {
      const std::string& key = item.key();
      if (std::none_of(known.begin(), known.end(), [&](const char* k) { return key == k; }))
        error(pointer + "/" + pointer_token(key),
              fmt::format("unknown key {} (known: {})", quote_token(key), fmt::join(known, ", ")));
    }
  }

  std::string string_at(const nlohmann::json& doc, const std::string& pointer) {
    const auto& v = doc.at(nlohmann::json::json_pointer(pointer));
    if (!v.is_string()) error(pointer, fmt::format("\"{}\" must be a string", pointer.substr(1)));
    return v.get<std::string>();
  }

  float number_at(const nlohmann::json& v, const std::string& pointer, const char* what) {
    if (!v.is_number()) error(pointer, fmt::format("{} must be a number", what));
    const double d = v.get<double>();
    if (!std::isfinite(d) || std::abs(d) > 1e30) error(pointer, fmt::format("{} is out of range", what));
    return float(d);
  }

  Vec3 vec3_at(const nlohmann::json& v, const std::string& pointer, const char* what) {
    if (!v.is_array() || v.size() != 3) error(pointer, fmt::format("{} must be an array of 3 numbers", what));
    Vec3 out;
    for (int k = 0; k < 3; ++k) out[k] = number_at(v[size_t(k)], pointer + "/" + std::to_string(k), what);
    return out;
  }

  Vec3 colour_at(const nlohmann::json& v, const std::string& pointer, const char* what, float hi) {
    const Vec3 c = vec3_at(v, pointer, what);
    if (!(c.x >= 0 && c.y >= 0 && c.z >= 0 && c.x <= hi && c.y <= hi && c.z <= hi))
      error(pointer, fmt::format("{} values must lie in [0, {}]", what, hi));
    return c;
  }

  void apply_camera(const nlohmann::json& cam, CameraSpec* spec) {
    if (!cam.is_object()) error("/camera", "\"camera\" must be an object");
    check_keys(cam, "/camera", {"eye", "look", "up", "fov"});
    if (cam.contains("eye")) spec->eye = vec3_at(cam["eye"], "/camera/eye", "camera eye");
    if (cam.contains("look")) spec->look = vec3_at(cam["look"], "/camera/look", "camera look");
    if (cam.contains("up")) spec->up = vec3_at(cam["up"], "/camera/up", "camera up");
    if (cam.contains("fov")) spec->fov_y_degrees = number_at(cam["fov"], "/camera/fov", "camera fov");
    if (auto reason = spec->validate()) error("/camera", *reason);
  }

  void apply_materials(const nlohmann::json& mats, const std::vector<GlossyDefaults>& glossy, Scene* scene) {
    if (!mats.is_object()) error("/materials", "\"materials\" must be an object");
    for (const auto& item : mats.items()) {
      const std::string& name = item.key();
      const nlohmann::json& o = item.value();
      const std::string p = "/materials/" + pointer_token(name);
      const auto named = [&](const Material& m) { return m.name == name; };
      if (std::none_of(scene->materials.begin(), scene->materials.end(), named)) {
        std::vector<std::string> names;
        for (const Material& m : scene->materials)
          if (names.size() < 20) names.push_back(m.name);
        error(p, fmt::format("no material named '{}' in the scene (it has: {})", name, fmt::join(names, ", ")));
      }
      if (!o.is_object()) error(p, fmt::format("material override '{}' must be an object", name));
      check_keys(o, p, {"kd", "ke", "type", "ks", "exponent"});
      for (size_t i = 0; i < scene->materials.size(); ++i) {
        Material& m = scene->materials[i];
        if (m.name != name) continue;
        if (o.contains("kd")) {
          m.kd = colour_at(o["kd"], p + "/kd", "kd", 1.f);
          m.kd_texture = -1;  // a constant kd replaces the texture
        }
        if (o.contains("ke")) m.ke = colour_at(o["ke"], p + "/ke", "ke", 1e6f);
        if (o.contains("type")) {
          const auto& t = o["type"];
          if (t == "glossy") {
            if (m.diffuse()) {  // start from the MTL's Ks and Ns
              m.type = MaterialType::kGlossy;
              m.ks = i < glossy.size() ? glossy[i].ks : Vec3(0.f);
              m.exponent = i < glossy.size() ? glossy[i].exponent : Material{}.exponent;
            }
          } else if (t == "diffuse") {
            m.type = MaterialType::kDiffuse;
            m.ks = Vec3(0.f);
          } else {
            error(p + "/type", "material type must be \"diffuse\" or \"glossy\"");
          }
        }
        if (o.contains("ks") || o.contains("exponent")) {
          if (m.diffuse())
            error(p + (o.contains("ks") ? "/ks" : "/exponent"),
                  fmt::format("material '{}' is diffuse: add \"type\": \"glossy\" to use ks and exponent", name));
          if (o.contains("ks")) m.ks = colour_at(o["ks"], p + "/ks", "ks", 1.f);
          if (o.contains("exponent")) {
            m.exponent = number_at(o["exponent"], p + "/exponent", "exponent");
            if (!(m.exponent > 0.f && m.exponent <= 1e6f)) error(p + "/exponent", "exponent must lie in (0, 1e6]");
          }
        }
        if (!m.diffuse() && is_black(m.ks))
          scene_log()->warn("{}:{}: glossy material '{}' has ks 0 and renders as diffuse", path_, line(p), name);
        if (max_component(m.kd + m.ks) > 1.f)
          scene_log()->warn("{}:{}: material '{}' reflects more than it receives (kd + ks > 1)", path_, line(p), name);
      }
    }
  }

  std::string path_;
  const LoadOptions& opts_;
  std::unique_ptr<JsonLines> lines_;
};

bool ends_with_json(const std::string& s) {
  if (s.size() < 5) return false;
  std::string ext = s.substr(s.size() - 5);
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext == ".json";
}

}  // namespace

Scene load_obj(const std::string& obj_path, const LoadOptions& opts) {
  const fs::path real = canonical_or_fail(obj_path, obj_path);
  Scene scene = load_obj_inside({real, obj_path}, real.parent_path(), opts, nullptr);
  validate_or_fail(scene, obj_path);
  return scene;
}

Scene load_scene_json(const std::string& json_path, const LoadOptions& opts) {
  return JsonSceneReader(json_path, opts).read();
}

Scene load_scene(const std::string& spec, const LoadOptions& opts) {
  if (spec.rfind("builtin:", 0) == 0) return make_builtin_scene(parse_builtin_spec(spec.substr(8)), opts.max_triangles);
  if (ends_with_json(spec)) return load_scene_json(spec, opts);
  return load_obj(spec, opts);
}

}  // namespace epr
