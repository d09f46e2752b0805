// Pinhole camera. Raster space: x in [0, width) to the right, y in [0, height) downwards (row 0 is the
// top of the image), pixel (i, j) covers [i, i+1) x [j, j+1). World space is right-handed, metres.
//
// The reprojector's shaders mirror `project` exactly (same operations, same order): keep them in step.
#pragma once

#include <optional>
#include <string>

#include "common/math.h"

namespace epr {

struct CameraSpec {
  Vec3 eye{0, 1, 3.9f};
  Vec3 look{0, 1, 0};
  Vec3 up{0, 1, 0};
  float fov_y_degrees = 39.3077f;  // vertical field of view

  /// Empty if usable; otherwise the reason (non-finite values, eye == look, up parallel to view...).
  std::optional<std::string> validate() const;
};

struct Ray {
  Vec3 origin;
  Vec3 dir;  // unit length
};

class Camera {
 public:
  Camera() = default;
  Camera(const CameraSpec& spec, int width, int height);

  /// Primary ray through raster position (rx, ry).
  Ray generate_ray(float rx, float ry) const {
    const float sx = (2 * rx / float(width_) - 1) * tan_half_x_;
    const float sy = (1 - 2 * ry / float(height_)) * tan_half_y_;
    return {eye_, normalize(forward_ + right_ * sx + up_ * sy)};
  }

  /// Raster position of world point p, or false if p is not strictly in front of the eye.
  /// The result may lie outside the image: the caller culls against [0,W) x [0,H).
  bool project(const Vec3& p, float* rx, float* ry) const {
    const Vec3 d = p - eye_;
    const float z = dot(d, forward_);
    if (!(z > 0)) return false;
    const float sx = dot(d, right_) / z;
    const float sy = dot(d, up_) / z;
    *rx = (sx / tan_half_x_ + 1) * 0.5f * float(width_);
    *ry = (1 - sy / tan_half_y_) * 0.5f * float(height_);
    return true;
  }

  const Vec3& eye() const { return eye_; }
  const Vec3& forward() const { return forward_; }
  const Vec3& right() const { return right_; }
  const Vec3& up() const { return up_; }
  float tan_half_x() const { return tan_half_x_; }
  float tan_half_y() const { return tan_half_y_; }
  int width() const { return width_; }
  int height() const { return height_; }
  const CameraSpec& spec() const { return spec_; }

 private:
  CameraSpec spec_;
  Vec3 eye_, forward_, right_, up_;
  float tan_half_x_ = 1, tan_half_y_ = 1;
  int width_ = 1, height_ = 1;
};

}  // namespace epr
