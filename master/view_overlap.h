// How much two cameras' views of a scene share (DESIGN.md "Frame windows", cuts): the part of what
// camera a sees that camera b sees too. A frame window stops at a cut between frames whose views
// share too little (window_run.h).
//
// Each camera's view is a coarse deep framebuffer of its own (one texel per pixel of a
// kViewProbeSide-texel-wide image of the camera's aspect), rasterised with OpenGL where the caller has
// a context, else cast on the CPU (deep_framebuffer.h: the two differ only where an edge passes through
// a texel centre): a function of the scene and the camera, whatever reprojector the frame uses. A covered texel of a's
// view is shared when its point projects into b's image, faces b on the side a sees it from, and lies on the plane b
// sees there (within kViewProbeTolerance of its distance from b's eye); anything else -- outside b's
// image, behind b's surfaces, seen by b from behind -- is not.
#pragma once

#include <vector>

#include "common/camera.h"
#include "common/scene.h"
#include "master/deep_framebuffer.h"

namespace epr {

class GlContext;

/// The coarse view's longer side, in texels.
inline constexpr int kViewProbeSide = 128;
/// The plane test's tolerance, a fraction of the point's distance from the other eye.
inline constexpr float kViewProbeTolerance = 0.01f;

/// A camera's coarse view (see the file comment).
struct ViewProbe {
  Camera camera;  // the camera at the probe's resolution
  DeepFramebuffer view;
};

/// The coarse view of `spec` for an image of `width` x `height` pixels (its aspect); `gl`, if given,
/// must be current on the calling thread.
ViewProbe view_probe(const Scene& scene, const CameraSpec& spec, int width, int height, GlContext* gl = nullptr);

/// The fraction of a's covered texels that b sees too (see the file comment); 1 if a sees nothing.
double view_share(const ViewProbe& a, const ViewProbe& b);

/// min(view_share(a, b), view_share(b, a)): how much the two views share, either way.
double mutual_view_share(const ViewProbe& a, const ViewProbe& b);

}  // namespace epr
