// One direction sampled from a BSDF (worker/bsdf.h, worker/bsdf_ggx.h).
#pragma once

#include "common/math.h"

namespace epr {

struct BsdfSample {
  Vec3 wi;
  Vec3 weight;    // f * |cos| / pdf
  float pdf = 0;  // solid-angle density of wi (the mixture of all lobes), 1/sr; a probability if delta
  bool valid = false;
  bool delta = false;  // from a perfectly smooth lobe: no other technique (next event estimation) finds wi
};

}  // namespace epr
