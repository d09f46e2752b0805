// tinygltf compiled into the fuzz build, so that it is instrumented like the code that calls it. Same
// configuration as the loader includes it with (common/scene_loader/gltf_files.h: no stb_image).
#define TINYGLTF_IMPLEMENTATION
#include "common/scene_loader/gltf_files.h"
