#include "common/builtin_scenes.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <set>
#include <string_view>
#include <utility>

namespace epr {
namespace {

constexpr int kMaxTessellation = 4096;

// ---------------------------------------------------------------------------------------------------
// Geometry builder: counts triangles, or appends them to a scene.
// ---------------------------------------------------------------------------------------------------

/// The point i/n of the way from p to q, computed from the nearer end: the same point of the segment
/// walked from q (i' = n - i) comes out bit-identical, so neighbouring quads share edge vertices
/// exactly and closed meshes have no cracks.
Vec3 edge_point(const Vec3& p, const Vec3& q, int i, int n) {
  if (2 * i == n) return (p + q) * 0.5f;
  if (2 * i < n) return p + (q - p) * (float(i) / float(n));
  return q + (p - q) * (float(n - i) / float(n));
}

class Builder {
 public:
  /// With count_only the builder only counts triangles (materials are still recorded).
  Builder(Scene& scene, int tessellation, bool count_only) : s_(scene), n_(tessellation), count_only_(count_only) {}

  uint32_t material(const std::string& name, Vec3 kd, Vec3 ke = Vec3(0.f)) {
    Material m;
    m.name = name;
    m.kd = kd;
    m.ke = ke;
    return add_material(s_, std::move(m));
  }
  Material& material_ref(uint32_t id) { return s_.materials[id]; }

  /// The quad a-b-c-d (counter-clockwise seen from the front), split into n x n cells. At n = 1 the
  /// quad is split along its shorter diagonal, ties along b-d, as the OBJ loader splits quads
  /// (common/scene_loader/polygon.h), so the Cornell box has the loaded OBJ's triangles.
  void quad(Vec3 a, Vec3 b, Vec3 c, Vec3 d, uint32_t mat) {
    const int n = n_;
    triangles_ += 2 * size_t(n) * size_t(n);
    if (count_only_) return;
    if (!(dot(c - a, c - a) < dot(d - b, d - b))) {
      const Vec3 t = a;
      a = b, b = c, c = d, d = t;
    }
    const uint32_t base = uint32_t(s_.positions.size());
    for (int j = 0; j <= n; ++j) {
      const Vec3 left = edge_point(a, d, j, n), right = edge_point(b, c, j, n);
      for (int i = 0; i <= n; ++i) s_.positions.push_back(edge_point(left, right, i, n));
    }
    auto idx = [&](int i, int j) { return base + uint32_t(j * (n + 1) + i); };
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        s_.triangles.push_back({idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)});
        s_.triangles.push_back({idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)});
        s_.material_of.push_back(mat);
        s_.material_of.push_back(mat);
      }
  }

  size_t triangles() const { return triangles_; }
  Scene& scene() { return s_; }

 private:
  Scene& s_;
  int n_;
  bool count_only_;
  size_t triangles_ = 0;
};

// Face masks for axis-aligned boxes.
enum BoxFace : unsigned { kXLo = 1, kXHi = 2, kYLo = 4, kYHi = 8, kZLo = 16, kZHi = 32, kAllFaces = 63 };

/// One face of the box [lo, hi]: the face on `axis` at hi (or lo), facing out of the box (or in).
void box_face(Builder& b, const Vec3& lo, const Vec3& hi, int axis, bool at_hi, bool inward, uint32_t mat) {
  const int u = (axis + 1) % 3, v = (axis + 2) % 3;  // e_u x e_v = e_axis
  auto corner = [&](bool uh, bool vh) {
    Vec3 p;
    p[axis] = at_hi ? hi[axis] : lo[axis];
    p[u] = uh ? hi[u] : lo[u];
    p[v] = vh ? hi[v] : lo[v];
    return p;
  };
  // (0,0) (1,0) (1,1) (0,1) faces +axis.
  const bool positive = at_hi != inward;
  if (positive)
    b.quad(corner(false, false), corner(true, false), corner(true, true), corner(false, true), mat);
  else
    b.quad(corner(false, false), corner(false, true), corner(true, true), corner(true, false), mat);
}

void box(Builder& b, const Vec3& lo, const Vec3& hi, uint32_t mat, unsigned faces = kAllFaces, bool inward = false) {
  for (int axis = 0; axis < 3; ++axis)
    for (int side = 0; side < 2; ++side)
      if (faces & (1u << (2 * axis + side))) box_face(b, lo, hi, axis, side == 1, inward, mat);
}

/// Horizontal rectangle [x0, x1] x [z0, z1] at height y, facing up or down.
void horizontal_quad(Builder& b, float x0, float x1, float z0, float z1, float y, bool up, uint32_t mat) {
  if (up)
    b.quad({x0, y, z0}, {x0, y, z1}, {x1, y, z1}, {x1, y, z0}, mat);
  else
    b.quad({x0, y, z0}, {x1, y, z0}, {x1, y, z1}, {x0, y, z1}, mat);
}

/// Vertical rectangle [x0, x1] x [y0, y1] in the plane z, facing +z or -z.
void vertical_quad_z(Builder& b, float x0, float x1, float y0, float y1, float z, bool plus_z, uint32_t mat) {
  if (plus_z)
    b.quad({x0, y0, z}, {x1, y0, z}, {x1, y1, z}, {x0, y1, z}, mat);
  else
    b.quad({x0, y0, z}, {x0, y1, z}, {x1, y1, z}, {x1, y0, z}, mat);
}

/// Side of a vertical prism over a regular `sides`-gon (a column), facing outwards, without caps.
void column(Builder& b, float cx, float cz, float radius, float y0, float y1, int sides, uint32_t mat) {
  std::vector<std::pair<float, float>> ring(size_t(sides) + 1);
  for (int k = 0; k < sides; ++k) {
    const double angle = 2.0 * 3.14159265358979323846 * double(k) / double(sides);
    ring[size_t(k)] = {float(double(cx) + double(radius) * std::cos(angle)),
                       float(double(cz) + double(radius) * std::sin(angle))};
  }
  ring[size_t(sides)] = ring[0];
  for (int k = 0; k < sides; ++k) {
    const auto [x0, z0] = ring[size_t(k)];
    const auto [x1, z1] = ring[size_t(k) + 1];
    b.quad({x1, y0, z1}, {x0, y0, z0}, {x0, y1, z0}, {x1, y1, z1}, mat);
  }
}

// ---------------------------------------------------------------------------------------------------
// cornell, glossy
// ---------------------------------------------------------------------------------------------------

// CornellBox-Original.obj with the fix described in scenes/cornell-box/README.md (both
// boxes' bottom faces use their own four vertices). Faces in file order, corners in file order.
struct CornellQuad {
  int material;  // index into kCornellMaterials
  std::array<Vec3, 4> v;
};

struct CornellMaterial {
  const char* name;
  Vec3 kd, ke;
};

// Material order is the MTL file's, as the OBJ loader lists them.
constexpr std::array<CornellMaterial, 8> kCornellMaterials = {{
    {"leftWall", {0.63f, 0.065f, 0.05f}, {0, 0, 0}},
    {"rightWall", {0.14f, 0.45f, 0.091f}, {0, 0, 0}},
    {"floor", {0.725f, 0.71f, 0.68f}, {0, 0, 0}},
    {"ceiling", {0.725f, 0.71f, 0.68f}, {0, 0, 0}},
    {"backWall", {0.725f, 0.71f, 0.68f}, {0, 0, 0}},
    {"shortBox", {0.725f, 0.71f, 0.68f}, {0, 0, 0}},
    {"tallBox", {0.725f, 0.71f, 0.68f}, {0, 0, 0}},
    {"light", {0.78f, 0.78f, 0.78f}, {17, 12, 4}},
}};
constexpr int kLeftWall = 0, kRightWall = 1, kFloor = 2, kCeiling = 3, kBackWall = 4, kShortBox = 5, kTallBox = 6,
              kLight = 7;

constexpr std::array<CornellQuad, 18> kCornellQuads = {{
    {kFloor, {{{-1.01f, 0.00f, 0.99f}, {1.00f, 0.00f, 0.99f}, {1.00f, 0.00f, -1.04f}, {-0.99f, 0.00f, -1.04f}}}},
    {kCeiling, {{{-1.02f, 1.99f, 0.99f}, {-1.02f, 1.99f, -1.04f}, {1.00f, 1.99f, -1.04f}, {1.00f, 1.99f, 0.99f}}}},
    {kBackWall, {{{-0.99f, 0.00f, -1.04f}, {1.00f, 0.00f, -1.04f}, {1.00f, 1.99f, -1.04f}, {-1.02f, 1.99f, -1.04f}}}},
    {kRightWall, {{{1.00f, 0.00f, -1.04f}, {1.00f, 0.00f, 0.99f}, {1.00f, 1.99f, 0.99f}, {1.00f, 1.99f, -1.04f}}}},
    {kLeftWall, {{{-1.01f, 0.00f, 0.99f}, {-0.99f, 0.00f, -1.04f}, {-1.02f, 1.99f, -1.04f}, {-1.02f, 1.99f, 0.99f}}}},
    // short box: top, left, front, right, back, bottom
    {kShortBox, {{{0.53f, 0.60f, 0.75f}, {0.70f, 0.60f, 0.17f}, {0.13f, 0.60f, 0.00f}, {-0.05f, 0.60f, 0.57f}}}},
    {kShortBox, {{{-0.05f, 0.00f, 0.57f}, {-0.05f, 0.60f, 0.57f}, {0.13f, 0.60f, 0.00f}, {0.13f, 0.00f, 0.00f}}}},
    {kShortBox, {{{0.53f, 0.00f, 0.75f}, {0.53f, 0.60f, 0.75f}, {-0.05f, 0.60f, 0.57f}, {-0.05f, 0.00f, 0.57f}}}},
    {kShortBox, {{{0.70f, 0.00f, 0.17f}, {0.70f, 0.60f, 0.17f}, {0.53f, 0.60f, 0.75f}, {0.53f, 0.00f, 0.75f}}}},
    {kShortBox, {{{0.13f, 0.00f, 0.00f}, {0.13f, 0.60f, 0.00f}, {0.70f, 0.60f, 0.17f}, {0.70f, 0.00f, 0.17f}}}},
    {kShortBox, {{{0.53f, 0.00f, 0.75f}, {0.70f, 0.00f, 0.17f}, {0.13f, 0.00f, 0.00f}, {-0.05f, 0.00f, 0.57f}}}},
    // tall box: top, left, back, right, front, bottom
    {kTallBox, {{{-0.53f, 1.20f, 0.09f}, {0.04f, 1.20f, -0.09f}, {-0.14f, 1.20f, -0.67f}, {-0.71f, 1.20f, -0.49f}}}},
    {kTallBox, {{{-0.53f, 0.00f, 0.09f}, {-0.53f, 1.20f, 0.09f}, {-0.71f, 1.20f, -0.49f}, {-0.71f, 0.00f, -0.49f}}}},
    {kTallBox, {{{-0.71f, 0.00f, -0.49f}, {-0.71f, 1.20f, -0.49f}, {-0.14f, 1.20f, -0.67f}, {-0.14f, 0.00f, -0.67f}}}},
    {kTallBox, {{{-0.14f, 0.00f, -0.67f}, {-0.14f, 1.20f, -0.67f}, {0.04f, 1.20f, -0.09f}, {0.04f, 0.00f, -0.09f}}}},
    {kTallBox, {{{0.04f, 0.00f, -0.09f}, {0.04f, 1.20f, -0.09f}, {-0.53f, 1.20f, 0.09f}, {-0.53f, 0.00f, 0.09f}}}},
    {kTallBox, {{{-0.53f, 0.00f, 0.09f}, {0.04f, 0.00f, -0.09f}, {-0.14f, 0.00f, -0.67f}, {-0.71f, 0.00f, -0.49f}}}},
    {kLight, {{{-0.24f, 1.98f, 0.16f}, {-0.24f, 1.98f, -0.22f}, {0.23f, 1.98f, -0.22f}, {0.23f, 1.98f, 0.16f}}}},
}};

void build_cornell(Builder& b) {
  for (const auto& m : kCornellMaterials) b.material(m.name, m.kd, m.ke);
  // The light panel shines downwards only, as the measured box's does (its quad faces down): no
  // light enters the 1 cm gap between it and the ceiling from above.
  b.material_ref(kLight).emits_front_only = true;
  for (const auto& q : kCornellQuads) b.quad(q.v[0], q.v[1], q.v[2], q.v[3], uint32_t(q.material));
  b.scene().camera = CameraSpec{};  // the box's conventional camera (see camera.h)
}

void build_glossy(Builder& b) {
  build_cornell(b);
  // Kd + Ks stays below 1 so the material conserves energy.
  Material& m = b.material_ref(kTallBox);
  m.type = MaterialType::kGlossy;
  m.kd = Vec3(0.725f, 0.71f, 0.68f) * 0.4f;
  m.ks = Vec3(0.6f);
  m.exponent = 200.f;
}

// ---------------------------------------------------------------------------------------------------
// conference
// ---------------------------------------------------------------------------------------------------

/// A chair whose front faces direction (fx, fz) (a unit axis vector), seat centred at (cx, cz).
void chair(Builder& b, float cx, float cz, float fx, float fz, uint32_t mat) {
  // Local frame: x' across the chair, z' backwards (away from the table). World = centre + x' r + z' f',
  // r = (-fz, fx) is the front's right-hand side, f' = -(fx, fz).
  auto local_box = [&](float x0, float x1, float y0, float y1, float z0, float z1, unsigned faces) {
    const float ax = cx + x0 * -fz - z0 * fx, az = cz + x0 * fx - z0 * fz;
    const float bx = cx + x1 * -fz - z1 * fx, bz = cz + x1 * fx - z1 * fz;
    box(b, {std::min(ax, bx), y0, std::min(az, bz)}, {std::max(ax, bx), y1, std::max(az, bz)}, mat, faces);
  };
  const float h = 0.23f;                             // half the seat's width and depth
  local_box(-h, h, 0.44f, 0.49f, -h, h, kAllFaces);  // seat
  for (float sx : {-1.f, 1.f})
    for (float sz : {-1.f, 1.f})
      local_box(sx * h - 0.02f * sx - 0.02f, sx * h - 0.02f * sx + 0.02f, 0.f, 0.44f, sz * h - 0.02f * sz - 0.02f,
                sz * h - 0.02f * sz + 0.02f, kXLo | kXHi | kZLo | kZHi);           // legs
  local_box(-h, h, 0.49f, 0.95f, h - 0.05f, h, kXLo | kXHi | kYHi | kZLo | kZHi);  // backrest
}

void build_conference(Builder& b) {
  const uint32_t floor = b.material("carpet", {0.32f, 0.29f, 0.26f});
  const uint32_t walls = b.material("wall", {0.75f, 0.73f, 0.69f});
  const uint32_t ceiling = b.material("ceiling", {0.8f, 0.8f, 0.8f});
  const uint32_t wood = b.material("table", {0.5f, 0.3f, 0.15f});
  const uint32_t fabric = b.material("chair", {0.18f, 0.24f, 0.5f});
  const uint32_t board = b.material("whiteboard", {0.85f, 0.85f, 0.85f});
  const uint32_t picture = b.material("picture", {0.8f, 0.45f, 0.1f});
  const uint32_t light = b.material("light", {0.8f, 0.8f, 0.8f}, {16.f, 15.5f, 14.5f});

  // Room 12 x 3 x 8 m, inside faces.
  const Vec3 lo(-6.f, 0.f, -4.f), hi(6.f, 3.f, 4.f);
  box_face(b, lo, hi, 1, false, true, floor);
  box_face(b, lo, hi, 1, true, true, ceiling);
  for (int axis : {0, 2})
    for (bool at_hi : {false, true}) box_face(b, lo, hi, axis, at_hi, true, walls);

  // Six light panels 1.8 x 0.6 m, 1 cm below the ceiling, facing down.
  for (float x : {-3.5f, 0.f, 3.5f})
    for (float z : {-1.5f, 1.5f}) horizontal_quad(b, x - 0.9f, x + 0.9f, z - 0.3f, z + 0.3f, 2.99f, false, light);

  // Whiteboard on the +x wall, a picture on the -z wall, 1 cm in front of them.
  b.quad({5.99f, 0.9f, -1.5f}, {5.99f, 0.9f, 1.5f}, {5.99f, 2.1f, 1.5f}, {5.99f, 2.1f, -1.5f}, board);
  vertical_quad_z(b, -2.f, 1.f, 1.0f, 2.2f, -3.99f, true, picture);

  // Table 5 x 1.6 m, top 0.72 .. 0.76 m, four legs.
  box(b, {-2.5f, 0.72f, -0.8f}, {2.5f, 0.76f, 0.8f}, wood);
  for (float x : {-2.3f, 2.3f})
    for (float z : {-0.6f, 0.6f})
      box(b, {x - 0.04f, 0.f, z - 0.04f}, {x + 0.04f, 0.72f, z + 0.04f}, wood, kXLo | kXHi | kZLo | kZHi);

  // Five chairs along each long side, one at each end, all facing the table.
  for (float x : {-2.f, -1.f, 0.f, 1.f, 2.f}) {
    chair(b, x, 1.25f, 0.f, -1.f, fabric);
    chair(b, x, -1.25f, 0.f, 1.f, fabric);
  }
  chair(b, 3.1f, 0.f, -1.f, 0.f, fabric);
  chair(b, -3.1f, 0.f, 1.f, 0.f, fabric);

  b.scene().camera = CameraSpec{{-5.3f, 1.6f, 3.4f}, {0.5f, 0.7f, -0.7f}, {0, 1, 0}, 55.f};
}

// ---------------------------------------------------------------------------------------------------
// hall, wall
// ---------------------------------------------------------------------------------------------------

void build_hall(Builder& b) {
  const uint32_t floor = b.material("floor", {0.55f, 0.5f, 0.42f});
  const uint32_t walls = b.material("wall", {0.7f, 0.62f, 0.5f});
  const uint32_t ceiling = b.material("ceiling", {0.6f, 0.55f, 0.48f});
  const uint32_t stone = b.material("column", {0.78f, 0.74f, 0.66f});
  const uint32_t gallery = b.material("gallery", {0.62f, 0.56f, 0.48f});
  const uint32_t wood = b.material("beam", {0.45f, 0.35f, 0.25f});
  const uint32_t sky = b.material("skylight", {0.f, 0.f, 0.f}, {9.f, 8.6f, 7.8f});
  const std::array<uint32_t, 3> drapes = {b.material("drape_red", {0.6f, 0.07f, 0.05f}),
                                          b.material("drape_green", {0.09f, 0.42f, 0.12f}),
                                          b.material("drape_blue", {0.08f, 0.14f, 0.55f})};

  // Hall 30 x 12 x 12 m (x, y, z), inside faces; the ceiling has a 3 m skylight strip along x.
  const Vec3 lo(-15.f, 0.f, -6.f), hi(15.f, 12.f, 6.f);
  box_face(b, lo, hi, 1, false, true, floor);
  for (int axis : {0, 2})
    for (bool at_hi : {false, true}) box_face(b, lo, hi, axis, at_hi, true, walls);
  horizontal_quad(b, -15.f, 15.f, -6.f, -1.5f, 12.f, false, ceiling);
  horizontal_quad(b, -15.f, 15.f, 1.5f, 6.f, 12.f, false, ceiling);
  horizontal_quad(b, -15.f, 15.f, -1.5f, 1.5f, 12.f, false, sky);

  for (float side : {-1.f, 1.f}) {
    const float zc = 3.5f * side;  // colonnade axis
    // Gallery floor 5 .. 5.3 m high from the colonnade to the outer wall.
    box(b, {-15.f, 5.f, side < 0 ? -6.f : 3.f}, {15.f, 5.3f, side < 0 ? -3.f : 6.f}, gallery,
        kYLo | kYHi | (side < 0 ? kZHi : kZLo));
    // Beam on the upper columns, 9 .. 9.4 m.
    box(b, {-15.f, 9.f, zc - 0.3f}, {15.f, 9.4f, zc + 0.3f}, wood, kYLo | kYHi | kZLo | kZHi);
    // Nine 12-gon columns below the gallery and nine above it.
    for (int k = 0; k < 9; ++k) {
      const float x = -12.f + 3.f * float(k);
      column(b, x, zc, 0.35f, 0.f, 5.f, 12, stone);
      column(b, x, zc, 0.25f, 5.3f, 9.f, 12, stone);
    }
    // Drapes hanging in four of the eight gaps between the upper columns, facing the nave.
    int colour = side < 0 ? 0 : 1;
    for (int gap : {1, 3, 4, 6}) {
      const float x0 = -12.f + 3.f * float(gap) + 0.35f, x1 = x0 + 2.3f;
      vertical_quad_z(b, x0, x1, 6.2f, 9.f, zc - 0.35f * side, side < 0, drapes[size_t(colour++ % 3)]);
    }
  }
}

void build_hall_view(Builder& b) {
  build_hall(b);
  // At one end, looking down the nave towards the far colonnade: the end wall behind, the near
  // colonnade and much of the ceiling are outside the view; the columns occlude the aisles.
  b.scene().camera = CameraSpec{{-13.f, 1.7f, -1.2f}, {0.f, 3.2f, 1.8f}, {0, 1, 0}, 55.f};
}

void build_wall(Builder& b) {
  build_hall(b);
  // 1 m in front of the -x end wall, looking straight at it.
  b.scene().camera = CameraSpec{{-14.f, 1.7f, 0.5f}, {-15.f, 1.7f, 0.5f}, {0, 1, 0}, 50.f};
}

// ---------------------------------------------------------------------------------------------------
// furnace
// ---------------------------------------------------------------------------------------------------

void build_furnace(Builder& b, float albedo, float emission) {
  const uint32_t m = b.material("furnace", Vec3(albedo), Vec3(emission));
  box(b, {-1.f, -1.f, -1.f}, {1.f, 1.f, 1.f}, m, kAllFaces, /*inward=*/true);
  b.scene().camera = CameraSpec{{0.4f, -0.3f, 0.4f}, {-1.f, 1.f, -1.f}, {0, 1, 0}, 60.f};
}

// ---------------------------------------------------------------------------------------------------
// Failure-mode study scenes (docs/FAILURE_MODES.md): thinwall, hiddenlight, grazing
// ---------------------------------------------------------------------------------------------------

void build_thinwall(Builder& b) {
  const uint32_t white = b.material("white", {0.75f, 0.75f, 0.75f});
  const uint32_t partition = b.material("partition", {0.75f, 0.75f, 0.75f});
  const uint32_t light = b.material("light", {0.8f, 0.8f, 0.8f}, {12.f, 12.f, 12.f});
  // Two 2 x 2 x 2 m rooms side by side, open at the front (z = 1), sharing one partition: a single
  // quad at x = 0 (zero thickness, two-sided). The light hangs in the left room; light leaving the
  // left room's open front travels to +z for ever, so the right room receives none at all.
  for (float side : {-1.f, 1.f}) {
    const Vec3 lo(side < 0 ? -2.f : 0.f, 0.f, -1.f), hi(side < 0 ? 0.f : 2.f, 2.f, 1.f);
    box_face(b, lo, hi, 1, false, true, white);     // floor
    box_face(b, lo, hi, 1, true, true, white);      // ceiling
    box_face(b, lo, hi, 2, false, true, white);     // back wall
    box_face(b, lo, hi, 0, side > 0, true, white);  // outer side wall
  }
  b.quad({0.f, 0.f, 1.f}, {0.f, 0.f, -1.f}, {0.f, 2.f, -1.f}, {0.f, 2.f, 1.f}, partition);  // faces +x
  horizontal_quad(b, -1.4f, -0.6f, -0.4f, 0.4f, 1.99f, false, light);
  // From the right, in front of the rooms: the dark room with the partition's right side, and the lit
  // room through its open front (the partition's lit side faces away from the camera).
  b.scene().camera = CameraSpec{{1.5f, 1.0f, 4.f}, {-0.5f, 1.0f, 0.f}, {0, 1, 0}, 55.f};
}

void build_hiddenlight(Builder& b) {
  const uint32_t walls = b.material("wall", {0.7f, 0.7f, 0.7f});
  const uint32_t tray = b.material("tray", {0.5f, 0.5f, 0.5f});
  const uint32_t light = b.material("light", {0.8f, 0.8f, 0.8f}, {40.f, 38.f, 34.f});
  // Closed 4 x 3 x 4 m room. The only emitter lies inside an open-top tray (single-layer quads, 20 cm
  // deep) hanging 40 cm under the ceiling: it lights the ceiling and the upper walls, and everything
  // the camera sees is lit only indirectly. No camera ray can reach the emitter.
  box(b, {-2.f, 0.f, -2.f}, {2.f, 3.f, 2.f}, walls, kAllFaces, /*inward=*/true);
  box(b, {-0.5f, 2.4f, -0.5f}, {0.5f, 2.6f, 0.5f}, tray, kXLo | kXHi | kYLo | kZLo | kZHi);
  horizontal_quad(b, -0.4f, 0.4f, -0.4f, 0.4f, 2.45f, true, light);
  b.scene().camera = CameraSpec{{0.f, 1.2f, 1.9f}, {0.f, 1.5f, -2.f}, {0, 1, 0}, 60.f};
}

void build_grazing(Builder& b) {
  const uint32_t floor = b.material("floor", {0.6f, 0.6f, 0.6f});
  const uint32_t walls = b.material("wall", {0.65f, 0.6f, 0.55f});
  const uint32_t blocks = b.material("block", {0.3f, 0.45f, 0.7f});
  const uint32_t light = b.material("light", {0.8f, 0.8f, 0.8f}, {10.f, 10.f, 10.f});
  // A closed corridor 6 x 3 x 22 m; the camera 50 cm above the floor looks down its length, so the
  // far floor is seen at grazing angles (below 3 degrees beyond 9.5 m, 1.3 degrees at the far end),
  // and three blocks give silhouettes against the far floor and walls.
  const Vec3 lo(-3.f, 0.f, -20.f), hi(3.f, 3.f, 2.f);
  box_face(b, lo, hi, 1, false, true, floor);
  box_face(b, lo, hi, 1, true, true, walls);
  for (int axis : {0, 2})
    for (bool at_hi : {false, true}) box_face(b, lo, hi, axis, at_hi, true, walls);
  for (float z : {-2.f, -8.f, -14.f}) horizontal_quad(b, -1.f, 1.f, z - 1.f, z + 1.f, 2.99f, false, light);
  box(b, {-1.5f, 0.f, -5.f}, {-0.5f, 0.4f, -4.f}, blocks, kAllFaces & ~kYLo);
  box(b, {0.3f, 0.f, -9.f}, {1.1f, 0.8f, -8.5f}, blocks, kAllFaces & ~kYLo);
  box(b, {-0.4f, 0.f, -15.f}, {0.4f, 0.05f, -13.f}, blocks, kAllFaces & ~kYLo);
  b.scene().camera = CameraSpec{{0.2f, 0.5f, 1.5f}, {0.f, 0.f, -20.f}, {0, 1, 0}, 40.f};
}

void build(Builder& b, const BuiltinSpec& spec) {
  if (spec.name == "cornell") return build_cornell(b);
  if (spec.name == "glossy") return build_glossy(b);
  if (spec.name == "conference") return build_conference(b);
  if (spec.name == "hall") return build_hall_view(b);
  if (spec.name == "wall") return build_wall(b);
  if (spec.name == "furnace") return build_furnace(b, spec.albedo, spec.emission);
  if (spec.name == "thinwall") return build_thinwall(b);
  if (spec.name == "hiddenlight") return build_hiddenlight(b);
  if (spec.name == "grazing") return build_grazing(b);
  throw SceneError(fmt::format("unknown built-in scene '{}'", spec.name));
}

// ---------------------------------------------------------------------------------------------------
// Names and parameters
// ---------------------------------------------------------------------------------------------------

[[noreturn]] void bad_spec(const std::string& text, const std::string& reason) {
  throw SceneError(fmt::format("builtin:{}: {}", text, reason));
}

template <typename T>
bool parse_number(std::string_view s, T* out) {
  if (s.empty()) return false;
  const char* end = s.data() + s.size();
  const auto [ptr, ec] = std::from_chars(s.data(), end, *out);
  return ec == std::errc() && ptr == end;
}

BuiltinSpec parse_spec(const std::string& text, bool* has_tess) {
  std::string_view rest(text);
  if (rest.substr(0, 8) == "builtin:") rest.remove_prefix(8);
  BuiltinSpec spec;
  const size_t q = rest.find('?');
  spec.name = std::string(rest.substr(0, q));
  auto names = builtin_scene_names();
  for (std::string& study : study_scene_names()) names.push_back(std::move(study));
  if (std::find(names.begin(), names.end(), spec.name) == names.end())
    bad_spec(text, fmt::format("unknown built-in scene '{}' (known: {})", spec.name, fmt::join(names, ", ")));
  *has_tess = false;
  if (q == std::string_view::npos) return spec;
  std::set<std::string, std::less<>> seen;
  std::string_view params = rest.substr(q + 1);
  for (bool more = true; more;) {
    const size_t amp = params.find('&');
    const std::string_view item = params.substr(0, amp);
    more = amp != std::string_view::npos;
    if (more) params.remove_prefix(amp + 1);
    const size_t eq = item.find('=');
    if (eq == std::string_view::npos) bad_spec(text, fmt::format("parameter '{}' is not key=value", item));
    const std::string_view key = item.substr(0, eq), value = item.substr(eq + 1);
    if (!seen.emplace(key).second) bad_spec(text, fmt::format("parameter '{}' given twice", key));
    if (key == "tess") {
      int n = 0;
      if (!parse_number(value, &n) || n < 1 || n > kMaxTessellation)
        bad_spec(text, fmt::format("tess must be an integer in [1, {}], not '{}'", kMaxTessellation, value));
      spec.tessellation = n;
      *has_tess = true;
    } else if ((key == "albedo" || key == "emission") && spec.name != "furnace") {
      bad_spec(text, fmt::format("only the furnace scene takes '{}'", key));
    } else if (key == "albedo") {
      float a = 0;
      if (!parse_number(value, &a) || !(a >= 0.f && a < 1.f))
        bad_spec(text, fmt::format("albedo must be a number in [0, 1), not '{}'", value));
      spec.albedo = a;
    } else if (key == "emission") {
      float e = 0;
      if (!parse_number(value, &e) || !(e > 0.f && e <= 1e6f))
        bad_spec(text, fmt::format("emission must be a number in (0, 1e6], not '{}'", value));
      spec.emission = e;
    } else {
      bad_spec(text, fmt::format("unknown parameter '{}' (known: tess, and albedo, emission for furnace)", key));
    }
  }
  return spec;
}

}  // namespace

std::string BuiltinSpec::canonical() const {
  std::vector<std::string> params;
  if (tessellation != 1) params.push_back(fmt::format("tess={}", tessellation));
  if (name == "furnace") {
    if (albedo != BuiltinSpec{}.albedo) params.push_back(fmt::format("albedo={}", albedo));
    if (emission != BuiltinSpec{}.emission) params.push_back(fmt::format("emission={}", emission));
  }
  return params.empty() ? "builtin:" + name : fmt::format("builtin:{}?{}", name, fmt::join(params, "&"));
}

BuiltinSpec parse_builtin_spec(const std::string& text) {
  bool has_tess = false;
  return parse_spec(text, &has_tess);
}

std::vector<std::string> builtin_scene_names() {
  return {"cornell", "conference", "hall", "wall", "glossy", "furnace"};
}

std::vector<std::string> study_scene_names() { return {"thinwall", "hiddenlight", "grazing"}; }

size_t builtin_triangle_count(const BuiltinSpec& spec) {
  if (spec.tessellation < 1 || spec.tessellation > kMaxTessellation)
    throw SceneError(
        fmt::format("{}: tessellation {} is outside [1, {}]", spec.canonical(), spec.tessellation, kMaxTessellation));
  Scene scratch;
  Builder counter(scratch, spec.tessellation, /*count_only=*/true);
  build(counter, spec);
  return counter.triangles();
}

Scene make_builtin_scene(const BuiltinSpec& spec, size_t max_triangles) {
  const size_t count = builtin_triangle_count(spec);
  if (count > max_triangles)
    throw SceneError(fmt::format("{}: {} triangles exceed the limit of {}", spec.canonical(), count, max_triangles));
  Scene scene;
  scene.name = spec.canonical();
  scene.triangles.reserve(count);
  scene.material_of.reserve(count);
  Builder builder(scene, spec.tessellation, /*count_only=*/false);
  build(builder, spec);
  scene.validate();
  return scene;
}

Scene make_builtin_scene(const std::string& name, int tessellation) {
  bool has_tess = false;
  BuiltinSpec spec = parse_spec(name, &has_tess);
  if (!has_tess) spec.tessellation = tessellation;
  return make_builtin_scene(spec);
}

}  // namespace epr
