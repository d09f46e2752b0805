// A camera animated by keyframes, from a scene JSON's "animation" (scenes/README.md, "Camera
// animation"). Frames are integers; each key is a whole camera (the fields a key leaves out were
// completed from the key before it, the first key's from the scene's camera). Between two keys the
// eye, the look-at point, the up vector and the field of view move linearly; before the first key
// the camera is the first key's, after the last key the last key's. Interpolating the look-at point
// (not the direction) keeps a camera aimed at a point while it moves, and moves the aim in a
// straight line when two keys look at different points.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "common/camera.h"
#include "common/scene_error.h"

namespace epr {

/// Frame numbers run from 0 to kMaxFrame.
constexpr uint32_t kMaxFrame = 9'999'999;

struct CameraKey {
  uint32_t frame = 0;
  CameraSpec camera;  // complete and valid
  size_t line = 0;    // the key's line in the scene JSON, for messages
};

struct CameraAnimation {
  std::string file;             // the scene JSON as the user named it, for messages
  std::vector<CameraKey> keys;  // strictly increasing frames; empty: the camera does not move

  bool animated() const { return !keys.empty(); }
  /// The camera at `frame`; `still` when there are no keys.
  CameraSpec at(uint32_t frame, const CameraSpec& still) const;
  /// Nullopt when the camera at `frame` is usable; else "FILE:LINE: frame F: reason", naming the
  /// line of the key at or before the frame (two keys whose in-between camera degenerates, e.g. the
  /// eye passing through the look-at point).
  std::optional<std::string> frame_problem(uint32_t frame, const CameraSpec& still) const;
};

/// The camera animation of a scene: a scene JSON's "animation" (SceneError naming the file and line
/// when it is malformed, as load_scene does), no keys for other scenes. `still`, when given, receives
/// the scene's unanimated camera. Loads the whole scene, as load_scene does.
CameraAnimation load_camera_animation(const std::string& spec, const LoadOptions& = {}, CameraSpec* still = nullptr);

}  // namespace epr
