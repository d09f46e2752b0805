// Loaded scenes shared within one process, by their bundle's content hash: the embedded render's
// client, master and workers use the one copy the client loaded (parsed and its textures decoded
// once), and several in-process workers share the one a worker loaded. The shelf holds them weakly:
// a scene stays as long as one of its users holds it, and goes with the last.
//
// With each shelved scene goes its Embree BVH (common/scene_bvh.h: built on first use, shelved_bvh),
// shared by the workers' tracing and the master's frames; it stays while anyone holds the scene as
// the shelf handed it out (shelve_scene, shelved_scene) or the BVH itself.
//
// A shelved scene is complete (textures decoded) and has its own lighting (the scene's, not a job's):
// every user applies its job's lighting over it (job_lighting).
#pragma once

#include <memory>
#include <string>

#include "common/scene.h"
#include "common/scene_bvh.h"

namespace epr {

/// The scene shelved under `content_hash`, or null if no user holds one.
std::shared_ptr<const Scene> shelved_scene(const std::string& content_hash);

/// Shelves `scene` under `content_hash` unless a scene is shelved there already; returns the one
/// shelved (the caller's or the earlier one).
std::shared_ptr<const Scene> shelve_scene(const std::string& content_hash, std::shared_ptr<const Scene> scene);

/// The BVH of `scene`: the shelf's, if `scene` is a shelved scene (the same object for every caller,
/// built once), else one of the caller's own. Either holds a share of the scene; neither is built yet
/// if nobody asked it for its BVH.
std::shared_ptr<const SceneBvh> shelved_bvh(const std::shared_ptr<const Scene>& scene);

}  // namespace epr
