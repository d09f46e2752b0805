// Whether a camera can show a vertex: what worker/tile_renderer.cpp's filter keeps for reprojection
// (and counts by reason) and what the reuse roulette (worker/roulette.h) treats as reprojectable.
#pragma once

#include "common/camera.h"
#include "common/math.h"

namespace epr {

enum class ViewTest { kVisible, kOutsideImage, kBackFacing };

/// Tests `p` (geometric normal `n`) against the image at `S` x `S` subpixels per pixel: in front of
/// the eye and inside the image (its subpixel coordinates in *sx, *sy), and facing the eye.
inline ViewTest view_test(const Camera& cam, const Vec3& p, const Vec3& n, int S, float* sx, float* sy) {
  float rx, ry;
  if (!cam.project(p, &rx, &ry)) return ViewTest::kOutsideImage;
  *sx = rx * float(S);
  *sy = ry * float(S);
  const float sw = float(cam.width() * S), sh = float(cam.height() * S);
  if (!(*sx >= 0 && *sx < sw && *sy >= 0 && *sy < sh)) return ViewTest::kOutsideImage;
  if (!(dot(n, cam.eye() - p) > 0)) return ViewTest::kBackFacing;
  return ViewTest::kVisible;
}

}  // namespace epr
