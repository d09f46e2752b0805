#include "common/scene_loader/gltf_normals.h"

#include <fmt/format.h>

#include <cmath>

#include "common/scene_loader/gltf_accessor.h"
#include "common/scene_loader/text.h"

namespace epr::loader {
namespace {

using Mat3 = std::array<double, 9>;  // row-major

Mat3 linear_part(const std::array<double, 16>& m) {  // column-major 4x4 -> row-major 3x3
  return {m[0], m[4], m[8], m[1], m[5], m[9], m[2], m[6], m[10]};
}

double det(const Mat3& a) {
  return a[0] * (a[4] * a[8] - a[5] * a[7]) - a[1] * (a[3] * a[8] - a[5] * a[6]) + a[2] * (a[3] * a[7] - a[4] * a[6]);
}

/// The cofactor matrix: det(a) times the inverse transpose of a.
Mat3 cofactor(const Mat3& a) {
  return {a[4] * a[8] - a[5] * a[7], a[5] * a[6] - a[3] * a[8], a[3] * a[7] - a[4] * a[6],
          a[2] * a[7] - a[1] * a[8], a[0] * a[8] - a[2] * a[6], a[1] * a[6] - a[0] * a[7],
          a[1] * a[5] - a[2] * a[4], a[2] * a[3] - a[0] * a[5], a[0] * a[4] - a[1] * a[3]};
}

std::array<double, 3> apply(const Mat3& m, double x, double y, double z) {
  return {m[0] * x + m[1] * y + m[2] * z, m[3] * x + m[4] * y + m[5] * z, m[6] * x + m[7] * y + m[8] * z};
}

Vec3 unit_or_zero(const std::array<double, 3>& v) {
  const double l = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  if (!(l > 0) || !std::isfinite(l)) return Vec3(0.f);
  return {float(v[0] / l), float(v[1] / l), float(v[2] / l)};
}

void check(const std::array<double, 4>& e, size_t i, bool w_too, const std::string& file, const std::string& what) {
  const bool finite = std::isfinite(e[0]) && std::isfinite(e[1]) && std::isfinite(e[2]) && std::isfinite(e[3]);
  if (finite && (e[0] != 0 || e[1] != 0 || e[2] != 0) && (!w_too || e[3] != 0)) return;
  const std::string element =
      w_too ? fmt::format("{} element {} ({:g}, {:g}, {:g}, {:g})", what, i, e[0], e[1], e[2], e[3])
            : fmt::format("{} element {} ({:g}, {:g}, {:g})", what, i, e[0], e[1], e[2]);
  fail_file(file,
            element + (finite ? (w_too && e[3] == 0 ? " has handedness 0" : " has zero length") : " is not finite"));
}

RawVectors raw_vectors(const tinygltf::Model& m, int a, const std::string& where, const char* role, int type,
                       size_t count, const std::string& file) {
  const View v = accessor_view(m, a, where, role, file);
  const size_t n = type == TINYGLTF_TYPE_VEC3 ? 3 : 4;
  if (m.accessors[size_t(a)].type != type || v.component != TINYGLTF_COMPONENT_TYPE_FLOAT || v.count != count)
    fail_file(file,
              fmt::format("{}: {} accessors[{}] must be float VEC{} with one entry per POSITION", where, role, a, n));
  RawVectors raw(count);
  for (size_t i = 0; i < count; ++i)
    for (size_t k = 0; k < n; ++k) raw[i][k] = v.get(i, k);
  return raw;
}

}  // namespace

std::vector<Vec3> read_normals(const tinygltf::Model& m, const tinygltf::Primitive& prim, const std::string& where,
                               size_t count, const std::array<double, 16>& world, const std::string& file) {
  const auto it = prim.attributes.find("NORMAL");
  if (it == prim.attributes.end()) return {};
  return world_normals(raw_vectors(m, it->second, where, "NORMAL", TINYGLTF_TYPE_VEC3, count, file), world, file,
                       fmt::format("{}: NORMAL accessors[{}]", where, it->second));
}

std::vector<Tangent> read_tangents(const tinygltf::Model& m, const tinygltf::Primitive& prim, const std::string& where,
                                   size_t count, const std::array<double, 16>& world, const std::string& file) {
  const auto it = prim.attributes.find("TANGENT");
  if (it == prim.attributes.end()) return {};
  return world_tangents(raw_vectors(m, it->second, where, "TANGENT", TINYGLTF_TYPE_VEC4, count, file), world, file,
                        fmt::format("{}: TANGENT accessors[{}]", where, it->second));
}

std::vector<Vec3> world_normals(const RawVectors& raw, const std::array<double, 16>& world, const std::string& file,
                                const std::string& what) {
  const Mat3 a = linear_part(world);
  Mat3 n = cofactor(a);
  if (det(a) < 0)
    for (double& x : n) x = -x;
  std::vector<Vec3> out(raw.size());
  for (size_t i = 0; i < raw.size(); ++i) {
    check(raw[i], i, false, file, what);
    out[i] = unit_or_zero(apply(n, raw[i][0], raw[i][1], raw[i][2]));
  }
  return out;
}

std::vector<Tangent> world_tangents(const RawVectors& raw, const std::array<double, 16>& world, const std::string& file,
                                    const std::string& what) {
  const Mat3 a = linear_part(world);
  const float mirror = det(a) < 0 ? -1.f : 1.f;
  std::vector<Tangent> out(raw.size());
  for (size_t i = 0; i < raw.size(); ++i) {
    check(raw[i], i, true, file, what);
    out[i] = {unit_or_zero(apply(a, raw[i][0], raw[i][1], raw[i][2])), (raw[i][3] < 0 ? -1.f : 1.f) * mirror};
  }
  return out;
}

}  // namespace epr::loader
