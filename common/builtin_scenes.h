// Named built-in scenes that reproduce the paper's situations (DESIGN.md section 2), generated
// deterministically (no randomness; the same name gives bit-identical scenes on every call).
//
//   cornell     CornellBox-Original (the fixed OBJ in scenes/cornell-box): closed, mostly
//               visible, the best case. 36 triangles at tessellation 1. One difference: the light
//               emits from its lower (front) side only, as the real box's light panel does; the
//               OBJ's light emits from both sides, as Cycles' mesh lights do.
//   glossy      the Cornell box with a glossy tall box (ks 0.6, Phong exponent 200).
//   conference  closed 12 x 3 x 8 m meeting room: table, twelve chairs, six ceiling light panels.
//   hall        Sponza-like closed 30 x 12 x 12 m hall: two colonnades of 12-gon columns, an upper
//               gallery with a second row of columns and drapes, a skylight strip in the ceiling.
//               The camera stands at one end: about half of the surface is outside the view and
//               the columns occlude.
//   wall        the hall, seen from 1 m in front of an end wall: the worst case.
//   furnace     closed 2 m box, every face kd = albedo, ke = emission, normals inward: the radiance
//               is emission / (1 - albedo) everywhere.
//
// Scenes of the failure-mode study (docs/FAILURE_MODES.md), minimal and not among the six above:
//   thinwall    two rooms open at the front sharing a zero-thickness two-sided partition; the light
//               is in the left room, the right room receives no light at all (light leak test).
//   hiddenlight closed room lit only by an emitter inside an open-top tray under the ceiling: no
//               camera ray reaches the emitter, everything visible is lit indirectly.
//   grazing     long closed corridor seen from 15 cm above the floor (grazing angles) with three
//               blocks whose silhouettes stand against the far floor and walls.
//
// Names take parameters as "NAME?key=value&key=value":
//   tess=N        (all)      every quad becomes N x N cells (2 N^2 triangles), 1 <= N <= 4096
//   albedo=A      (furnace)  0 <= A < 1, default 0.5
//   emission=E    (furnace)  0 < E <= 1e6, default 1
//
// Tessellated quads put shared-edge vertices at bit-identical positions on both sides, so closed
// meshes stay watertight at every N (the furnace box is closed edge for edge).
// Units are metres, y is up.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "common/scene.h"
#include "common/scene_error.h"  // SceneError, LoadOptions

namespace epr {

/// A parsed built-in scene name with its parameters.
struct BuiltinSpec {
  std::string name;
  int tessellation = 1;
  float albedo = 0.5f;    // furnace only
  float emission = 1.0f;  // furnace only

  /// "builtin:NAME" plus the parameters that differ from their defaults, e.g. "builtin:hall?tess=4".
  std::string canonical() const;
};

/// Parses "NAME" or "NAME?key=value&..." (without the "builtin:" prefix). Throws SceneError for
/// unknown names, unknown or repeated keys and values out of range.
BuiltinSpec parse_builtin_spec(const std::string& text);

std::vector<std::string> builtin_scene_names();  // cornell, conference, hall, wall, glossy, furnace
/// The failure-mode study's scenes (thinwall, hiddenlight, grazing): accepted by the parser and
/// make_builtin_scene like the six, listed apart.
std::vector<std::string> study_scene_names();

/// Triangle count of the scene that make_builtin_scene would build, computed without building it.
size_t builtin_triangle_count(const BuiltinSpec& spec);

/// Builds the scene; throws SceneError if it would have more than max_triangles triangles.
Scene make_builtin_scene(const BuiltinSpec& spec, size_t max_triangles = LoadOptions{}.max_triangles);

/// `name` may carry parameters ("furnace?albedo=0.8"); a "tess" parameter there wins over
/// `tessellation`. Throws SceneError for unknown names.
Scene make_builtin_scene(const std::string& name, int tessellation = 1);

}  // namespace epr
