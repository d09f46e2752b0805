#include "common/camera_animation.h"

#include <fmt/format.h>

#include <algorithm>

namespace epr {
namespace {

Vec3 lerp(const Vec3& a, const Vec3& b, double t) {
  Vec3 out;
  for (int k = 0; k < 3; ++k) out[k] = float(double(a[k]) + (double(b[k]) - double(a[k])) * t);
  return out;
}

// The key at or before `frame` (the first key when the frame comes before it).
size_t key_index(const std::vector<CameraKey>& keys, uint32_t frame) {
  const auto after =
      std::upper_bound(keys.begin(), keys.end(), frame, [](uint32_t f, const CameraKey& k) { return f < k.frame; });
  return after == keys.begin() ? 0 : size_t(after - keys.begin()) - 1;
}

}  // namespace

CameraSpec CameraAnimation::at(uint32_t frame, const CameraSpec& still) const {
  if (keys.empty()) return still;
  const size_t i = key_index(keys, frame);
  const CameraKey& a = keys[i];
  if (frame <= a.frame || i + 1 == keys.size()) return a.camera;
  const CameraKey& b = keys[i + 1];
  const double t = double(frame - a.frame) / double(b.frame - a.frame);
  CameraSpec c;
  c.eye = lerp(a.camera.eye, b.camera.eye, t);
  c.look = lerp(a.camera.look, b.camera.look, t);
  c.up = lerp(a.camera.up, b.camera.up, t);
  c.fov_y_degrees =
      float(double(a.camera.fov_y_degrees) + (double(b.camera.fov_y_degrees) - double(a.camera.fov_y_degrees)) * t);
  return c;
}

std::optional<std::string> CameraAnimation::frame_problem(uint32_t frame, const CameraSpec& still) const {
  const auto reason = at(frame, still).validate();
  if (!reason) return std::nullopt;
  if (keys.empty()) return fmt::format("{}: frame {}: {}", file, frame, *reason);
  return fmt::format("{}:{}: frame {}: {}", file, keys[key_index(keys, frame)].line, frame, *reason);
}

}  // namespace epr
