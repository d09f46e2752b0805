#include "common/camera.h"

#include <fmt/format.h>

#include <cmath>
#include <stdexcept>
#include <utility>

#include "common/limits.h"

namespace epr {

std::optional<std::string> CameraSpec::validate() const {
  if (!is_finite(eye) || !is_finite(look) || !is_finite(up) || !std::isfinite(fov_y_degrees))
    return "camera has non-finite values";
  for (const auto& [what, v] : {std::pair{"eye", eye}, std::pair{"look-at point", look}, std::pair{"up vector", up}})
    if (!limits::within_coordinate_limit(v.x, v.y, v.z))
      return fmt::format("camera {} ({:g}, {:g}, {:g}) exceeds the magnitude limit {:g} (metres)", what, v.x, v.y, v.z,
                         limits::kMaxCoordinate);
  if (!(fov_y_degrees > 0.01f && fov_y_degrees < 179.f))
    return fmt::format("camera fov {} degrees is outside (0.01, 179)", fov_y_degrees);
  const Vec3 f = look - eye;
  if (!(length(f) > 1e-6f)) return "camera eye and look-at point coincide";
  if (!(length(up) > 1e-6f)) return "camera up vector is zero";
  if (!(length(cross(normalize(f), normalize(up))) > 1e-4f))
    return "camera up vector is parallel to the view direction";
  return std::nullopt;
}

Camera::Camera(const CameraSpec& spec, int width, int height) : spec_(spec), width_(width), height_(height) {
  if (auto err = spec.validate()) throw std::invalid_argument(*err);
  if (width <= 0 || height <= 0) throw std::invalid_argument("camera image size must be positive");
  eye_ = spec.eye;
  forward_ = normalize(spec.look - spec.eye);
  right_ = normalize(cross(forward_, spec.up));
  up_ = cross(right_, forward_);
  tan_half_y_ = std::tan(spec.fov_y_degrees * kPi / 360.f);
  tan_half_x_ = tan_half_y_ * float(width) / float(height);
}

}  // namespace epr
