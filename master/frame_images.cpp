// The images of a frame from its sums (frame_state.h: pathtrace_image, combined_image, counts_image).
#include <tbb/parallel_for.h>

#include "master/combine_rule.h"
#include "master/frame_state.h"

namespace epr {

Image pathtrace_image(const FrameImages& images) {
  if (images.path_sum.data.empty()) return images.pathtrace;
  const Image& s = images.path_sum;
  Image out(s.width, s.height, 3);
  tbb::parallel_for(0, s.height, [&](int y) {
    for (int x = 0; x < s.width; ++x) {
      const double m = images.path_count.at(x, y)[0];
      const float* ps = s.at(x, y);
      out.set_rgb(x, y, m > 0 ? Vec3(float(ps[0] / m), float(ps[1] / m), float(ps[2] / m)) : Vec3(0.f));
    }
  });
  return out;
}

Image combined_image(const FrameImages& images) {
  if (images.path_sum.data.empty()) return images.combined;
  if (images.reprojection.data.empty()) return pathtrace_image(images);
  const Image& s = images.path_sum;
  Image out(s.width, s.height, 3);
  const bool cross = !images.cross_combined.data.empty();
  const bool glossy = !images.glossy_sum.data.empty();
  tbb::parallel_for(0, s.height, [&](int y) {
    for (int x = 0; x < s.width; ++x) {
      const float* ps = s.at(x, y);
      const uint32_t m = uint32_t(images.path_count.at(x, y)[0]);
      // The glossy part is not combined: it comes back as its own mean (0 without one).
      const Vec3 g = glossy ? images.glossy_sum.rgb(x, y) : Vec3(0.f);
      const Vec3 diffuse_sum = glossy ? Vec3(ps[0], ps[1], ps[2]) - g : Vec3(ps[0], ps[1], ps[2]);
      // W M' (M' in samples: a multiple of 1 / 16 where a frame window weighs its neighbours'), or the
      // variance combination's estimate.
      const Vec3 combined =
          cross ? images.cross_combined.rgb(x, y)
                : combine_weighted(diffuse_sum, m,
                                   double(images.reprojected_weight) * double(images.reprojected.at(x, y)[0]),
                                   images.reprojection.rgb(x, y));
      out.set_rgb(x, y, glossy && m > 0 ? combined + g * (1.f / float(m)) : combined);
    }
  });
  return out;
}

Image counts_image(const FrameImages& images) {
  Image out(images.path_count.width, images.path_count.height, 2);
  for (int y = 0; y < out.height; ++y)
    for (int x = 0; x < out.width; ++x) {
      out.at(x, y)[0] = images.path_count.at(x, y)[0];
      out.at(x, y)[1] = images.reprojected.width ? images.reprojected.at(x, y)[0] : 0.f;
    }
  return out;
}

}  // namespace epr
