// The GLSL of GlReprojector (gl_reprojector.h). The kernels mirror detail::classify
// (reprojection_kernel.h) operation for operation; `precise` keeps the compiler from re-associating
// or fusing (llvmpipe also lowers ffma).
#include "master/gl_reprojector_shaders.h"

namespace epr::gl_shaders {

// ---- packed vertices: VertexCodec's decode in GLSL -------------------------------------------------
// The 16-byte wire record (common/vertex_codec.h) read as one RGBA32UI texel: x, y = position_bits
// (low, high word), z = normal_bits, w = radiance_bits. Each function is VertexCodec's decode_*
// operation for operation (double precision where the codec computes in double), so the decoded
// floats are bit for bit the CPU's (tests/master/gl_packed_test.cpp compares them on every edge case).
const char* const kPackedDecode = R"(
layout(std430, binding = 3) readonly buffer Codec { double codec[8]; };  // lo_q.xyz, 0, cell.xyz, 0

// VertexCodec::decode_position: float(lo_q + (q + 0.5) * cell) per axis, in double.
vec3 decode_position(uvec2 bits, dvec3 lo_q, dvec3 cell) {
  uvec3 q = uvec3(bits.x & 0x1fffffu, (bits.x >> 21) | ((bits.y & 0x3ffu) << 11), (bits.y >> 10) & 0x1fffffu);
  precise dvec3 p = lo_q + (dvec3(q) + 0.5LF) * cell;
  return vec3(p);
}

// VertexCodec::decode_normal: octahedral snorm16 pair, unfolded, normalised in double. x and y are
// never -0 (an integer over 32767), so copysign(1, x) is the sign of the integer.
vec3 decode_normal(uint bits) {
  int ix = int(bits << 16) >> 16;  // int16 two's complement, sign-extended
  int iy = int(bits) >> 16;
  precise double x = max(-1.0LF, double(ix) / 32767.0LF);
  precise double y = max(-1.0LF, double(iy) / 32767.0LF);
  precise double z = 1.0LF - abs(x) - abs(y);
  if (z < 0.0LF) {
    precise double fx = (1.0LF - abs(y)) * (ix < 0 ? -1.0LF : 1.0LF);
    precise double fy = (1.0LF - abs(x)) * (iy < 0 ? -1.0LF : 1.0LF);
    x = fx;
    y = fy;
  }
  precise double len = sqrt(x * x + y * y + z * z);
  precise double nx = x / len;
  precise double ny = y / len;
  precise double nz = z / len;
  return vec3(float(nx), float(ny), float(nz));
}

// VertexCodec::decode_radiance: m * 2^(E - 136), E = 0 black. Every product is exact in float (m < 256;
// below 2^-126 in two steps, so that the power of two itself stays a normal float).
vec3 decode_radiance(uint bits) {
  uint e = bits >> 24;
  if (e == 0u) return vec3(0.0);
  precise vec3 m = vec3(uvec3(bits & 0xffu, (bits >> 8) & 0xffu, (bits >> 16) & 0xffu));
  if (e >= 10u) return m * uintBitsToFloat((e - 9u) << 23);   // 2^(e-136), e - 136 >= -126
  precise vec3 hi = m * uintBitsToFloat((e + 55u) << 23);      // 2^(e-72)
  return hi * uintBitsToFloat(63u << 23);                      // 2^-64
}
)";

// ---- reprojection kernel -------------------------------------------------------------------------
// PACKED 0: 36-byte float records (reproject(); the CPU filtered glossy and non-finite ones).
// PACKED 1: 16-byte wire records (reproject_packed(); copied as they are, decoded here, glossy ones
// counted here unless GLOSSY).
const char* const kReprojectShader = R"(
layout(local_size_x = WORKGROUP_SIZE) in;

#if PACKED
uniform usamplerBuffer words;        // RGBA32UI, 1 texel per record: the 16-byte wire record
#else
uniform samplerBuffer records;       // RGB32F, 3 texels per record: position, normal, radiance
#endif
uniform usamplerBuffer texel_plane;  // R16UI or R32UI per texel: plane index, UNCOVERED if uncovered
uniform samplerBuffer planes;        // RGBA32F per entry: N.xyz, d
uniform usamplerBuffer crease_range; // RG32UI per creased entry (entry - first_creased): first, count
uniform samplerBuffer creases;       // RGBA32F per crease: oriented N.xyz, d (visible side > 0)
#if PREFETCH
uniform usamplerBuffer cell_view;    // RGBA32UI view of `cells`, only read to warm the cache
#endif
struct Cell { float r, g, b; uint n; };
layout(std430, binding = 0) buffer Accumulation { Cell cells[]; };
layout(std430, binding = 1) buffer Counters { uint counters[]; };  // COUNTERS per invocation

uniform int first;    // texel of the batch's first record in `records` / `words`
uniform uint count;   // records in the batch
uniform vec3 eye, forward_, right_, up_;
uniform float tan_half_x, tan_half_y, width_, height_, s, grid_w, grid_h, epsilon, crease_tolerance, min_normal_cosine;
uniform uint grid_wi, first_creased;
uniform uint band_base;  // the bound band's first subpixel: `cells` and `texel_plane` hold that band
uniform uint weight;     // what an accepted sample adds to its count, its radiance multiplied by it

void main() {
  uint gid = gl_GlobalInvocationID.x;
  uint stride = gl_NumWorkGroups.x * gl_WorkGroupSize.x;
  uint n_accepted = 0u, n_culled = 0u, n_backfacing = 0u, n_occluded = 0u, n_not_diffuse = 0u;
#if PACKED
  dvec3 lo_q = dvec3(codec[0], codec[1], codec[2]);
  dvec3 cell = dvec3(codec[4], codec[5], codec[6]);
#endif
  for (uint i = gid; i < count; i += stride) {
#if PACKED
    uvec4 w = texelFetch(words, first + int(i));
#if !GLOSSY
    if ((w.y & 0x80000000u) == 0u) { n_not_diffuse++; continue; }  // VertexCodec::kDiffuseBit
#endif
    vec3 p = decode_position(w.xy, lo_q, cell);
#else
    int base = first + 3 * int(i);
    vec3 p = texelFetch(records, base).xyz;
#endif
    // Camera::project, expression for expression.
    precise float dx = p.x - eye.x;
    precise float dy = p.y - eye.y;
    precise float dz = p.z - eye.z;
    precise float z = dx * forward_.x + dy * forward_.y + dz * forward_.z;
    if (!(z > 0.0)) { n_culled++; continue; }
    precise float sx = (dx * right_.x + dy * right_.y + dz * right_.z) / z;
    precise float sy = (dx * up_.x + dy * up_.y + dz * up_.z) / z;
    precise float rx = (sx / tan_half_x + 1.0) * 0.5 * width_;
    precise float ry = (1.0 - sy / tan_half_y) * 0.5 * height_;
    precise float gx = rx * s;
    precise float gy = ry * s;
    if (!(gx >= 0.0 && gx < grid_w && gy >= 0.0 && gy < grid_h)) { n_culled++; continue; }
#if PACKED
    vec3 n = decode_normal(w.z);
#else
    vec3 n = texelFetch(records, base + 1).xyz;
#endif
    precise float ex = eye.x - p.x;
    precise float ey = eye.y - p.y;
    precise float ez = eye.z - p.z;
    precise float facing = n.x * ex + n.y * ey + n.z * ez;
    if (!(facing > 0.0)) { n_backfacing++; continue; }
    uint idx = uint(gy) * grid_wi + uint(gx) - band_base;
#if PREFETCH
    // Issue the cell's cache miss as a vector gather now, next to the plane-index gather, so that
    // both misses overlap; the atomics below then hit the cache. (The value is used so that the
    // fetch is kept: a saturated count also stops accumulation.)
    uint warm = texelFetch(cell_view, int(idx)).w;
#endif
    uint plane = texelFetch(texel_plane, int(idx)).x;
#if PREFETCH
    if (warm == 0xffffffffu) { n_occluded++; continue; }
#endif
    if (plane == UNCOVERED) { n_occluded++; continue; }
    vec4 t = texelFetch(planes, int(plane));
    precise float dist = p.x * t.x + p.y * t.y + p.z * t.z - t.w;
    if (!(abs(dist) <= epsilon)) { n_occluded++; continue; }
    precise float cosine = n.x * t.x + n.y * t.y + n.z * t.z;
    if (!(abs(cosine) >= min_normal_cosine)) { n_occluded++; continue; }
    if (plane >= first_creased) {
      uvec2 r = texelFetch(crease_range, int(plane - first_creased)).xy;
      bool behind = false;
      for (uint c = r.x; c < r.x + r.y; ++c) {
        vec4 q = texelFetch(creases, int(c));
        precise float e = p.x * q.x + p.y * q.y + p.z * q.z - q.w;
        if (e < -crease_tolerance) { behind = true; break; }
      }
      if (behind) { n_occluded++; continue; }
    }
    n_accepted++;
#if PACKED
    vec3 L = decode_radiance(w.w);
#else
    vec3 L = texelFetch(records, base + 2).xyz;
#endif
    precise vec3 Lw = float(weight) * L;
    atomicAdd(cells[idx].r, Lw.r);
    atomicAdd(cells[idx].g, Lw.g);
    atomicAdd(cells[idx].b, Lw.b);
    atomicAdd(cells[idx].n, weight);
  }
  counters[COUNTERS * gid + 0u] += n_accepted;
  counters[COUNTERS * gid + 1u] += n_culled;
  counters[COUNTERS * gid + 2u] += n_backfacing;
  counters[COUNTERS * gid + 3u] += n_occluded;
  counters[COUNTERS * gid + 4u] += n_not_diffuse;
}
)";

// Decoding alone (GlReprojector::decode_packed): one invocation per record writes the decoded
// position, diffuse flag, normal and radiance as 12 words.
const char* const kDecodeShader = R"(
layout(local_size_x = 64) in;
uniform usamplerBuffer words;
layout(std430, binding = 2) writeonly buffer Decoded { uint decoded[]; };
uniform uint count;
void main() {
  uint i = gl_GlobalInvocationID.x;
  if (i >= count) return;
  uvec4 w = texelFetch(words, int(i));
  dvec3 lo_q = dvec3(codec[0], codec[1], codec[2]);
  dvec3 cell = dvec3(codec[4], codec[5], codec[6]);
  uvec3 p = floatBitsToUint(decode_position(w.xy, lo_q, cell));
  uvec3 n = floatBitsToUint(decode_normal(w.z));
  uvec3 L = floatBitsToUint(decode_radiance(w.w));
  uint o = 12u * i;
  decoded[o + 0u] = p.x; decoded[o + 1u] = p.y; decoded[o + 2u] = p.z; decoded[o + 3u] = w.y >> 31;
  decoded[o + 4u] = n.x; decoded[o + 5u] = n.y; decoded[o + 6u] = n.z; decoded[o + 7u] = 0u;
  decoded[o + 8u] = L.x; decoded[o + 9u] = L.y; decoded[o + 10u] = L.z; decoded[o + 11u] = 0u;
}
)";

// ---- exact-mode samples --------------------------------------------------------------------------
const char* const kExactShader = R"(
layout(local_size_x = WORKGROUP_SIZE) in;
uniform usamplerBuffer samples;  // RGBA32UI per sample: subpixel, radiance bits (validated on the CPU)
struct Cell { float r, g, b; uint n; };
layout(std430, binding = 0) buffer Accumulation { Cell cells[]; };
uniform int first;
uniform uint count;
uniform uint band_base;  // the bound band's first subpixel
void main() {
  uint stride = gl_NumWorkGroups.x * gl_WorkGroupSize.x;
  for (uint i = gl_GlobalInvocationID.x; i < count; i += stride) {
    uvec4 e = texelFetch(samples, first + int(i));
    uint c = e.x - band_base;
    atomicAdd(cells[c].r, uintBitsToFloat(e.y));
    atomicAdd(cells[c].g, uintBitsToFloat(e.z));
    atomicAdd(cells[c].b, uintBitsToFloat(e.w));
    atomicAdd(cells[c].n, 1u);
  }
}
)";

// Downsampling next to the accumulation: one invocation per pixel averages the means of its non-empty
// subpixels and sums their counts (reprojection_image.h), so a round's end reads back W x H pixels
// instead of the whole S*W x S*H grid (16x less for S = 4). Run per band: image_h is the band's
// pixel rows and `cells` the band's accumulation.
const char* const kDownsampleShader = R"(
layout(local_size_x = 64) in;
struct Cell { float r, g, b; uint n; };
layout(std430, binding = 0) readonly buffer Accumulation { Cell cells[]; };
layout(std430, binding = 2) writeonly buffer Pixels { vec4 pixels[]; };
uniform uint image_w;
uniform uint image_h;
uniform uint subpixels;
uniform uint grid_w;
void main() {
  // 64 pixels per workgroup; workgroups in rows of gl_NumWorkGroups.x (the count per dimension is bounded).
  uint p = (gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x) * 64u + gl_LocalInvocationID.x;
  if (p >= image_w * image_h) return;
  uint x = p % image_w, y = p / image_w;
  vec3 mean = vec3(0.0);
  uint total = 0u, non_empty = 0u;
  for (uint j = 0u; j < subpixels; ++j)
    for (uint i = 0u; i < subpixels; ++i) {
      Cell c = cells[(y * subpixels + j) * grid_w + x * subpixels + i];
      if (c.n == 0u) continue;
      mean += vec3(c.r, c.g, c.b) / float(c.n);
      total += c.n;
      non_empty += 1u;
    }
  pixels[p] = vec4(non_empty > 0u ? mean / float(non_empty) : vec3(0.0), uintBitsToFloat(total));
}
)";

}  // namespace epr::gl_shaders
