// How much two cameras' views of a scene share (DESIGN.md "Frame windows", cuts): the part of what
// camera a sees that camera b sees too. A frame window stops at a cut between frames whose views
// share too little (window_run.h).
//
// Each camera's view is a coarse grid of primary rays (one per texel of a kViewProbeSide-texel-wide
// image of the camera's aspect, through the texel centres, from the near plane on as the deep
// framebuffer sees), traced with the scene's BVH (common/scene_bvh.h: the one the frames' edge
// pixels use): their hit points and geometric normals, a function of the scene and the camera only.
// A point of a's view is shared when it projects into b's image, beyond b's near plane, faces b on
// the side a sees it from, and b's ray towards it meets nothing before it (nothing nearer to b than
// 1 - kViewProbeTolerance of its distance, a hole of a cut-out being nothing); anything else --
// outside b's image, hidden from b, seen by b from behind -- is not.
#pragma once

#include <vector>

#include "common/camera.h"
#include "common/scene_bvh.h"

namespace epr {

/// The coarse view's longer side, in texels.
inline constexpr int kViewProbeSide = 128;
/// What may lie in front of a point without hiding it from the other eye: a fraction of its distance.
inline constexpr float kViewProbeTolerance = 0.01f;

/// A camera's coarse view (see the file comment).
struct ViewProbe {
  Camera camera;              // the camera at the probe's resolution
  float near = 0;             // its near plane's distance from the eye along the view direction
  std::vector<Vec3> points;   // the hit point of each ray that hits a surface
  std::vector<Vec3> normals;  // its unit geometric normal
};

/// The coarse view of `spec` for an image of `width` x `height` pixels (its aspect). Builds the
/// scene's BVH unless it was built: not to be called from inside a TBB task (SceneBvh::bvh).
ViewProbe view_probe(const SceneBvh& scene, const CameraSpec& spec, int width, int height);

/// The fraction of a's points that b sees too (see the file comment); 1 if a sees nothing. Both
/// probes of `scene`, whose BVH they built.
double view_share(const ViewProbe& a, const ViewProbe& b, const SceneBvh& scene);

/// min(view_share(a, b), view_share(b, a)): how much the two views share, either way.
double mutual_view_share(const ViewProbe& a, const ViewProbe& b, const SceneBvh& scene);

}  // namespace epr
