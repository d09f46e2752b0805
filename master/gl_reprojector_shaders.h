// The compute shaders of GlReprojector, as GLSL source bodies (gl_reprojector.cpp prepends the
// #version line and the #defines of its settings).
#pragma once

namespace epr::gl_shaders {

extern const char* const kPackedDecode;      // VertexCodec's decode in GLSL (PACKED kernels)
extern const char* const kReprojectShader;   // the plane test and accumulation of vertices
extern const char* const kDecodeShader;      // packed records to floats (tests)
extern const char* const kExactShader;       // exact-mode samples into the accumulation
extern const char* const kDownsampleShader;  // subpixels to per-pixel L_rp and M'

}  // namespace epr::gl_shaders
