#include "worker/sky_light.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace epr {
namespace {

// Power heuristic (beta = 2) weight of density p_this against p_other; p_this > 0.
inline float power_heuristic(float p_this, float p_other) {
  const float r = p_other / p_this;
  return 1 / (1 + r * r);
}

}  // namespace

float triangle_share_for_power(double triangle_power, double sky_power) {
  if (!(triangle_power > 0)) return 0;
  if (!(sky_power > 0)) return 1;
  return std::clamp(float(triangle_power / (triangle_power + sky_power)), kMinLightShare, 1 - kMinLightShare);
}

SkyLight::SkyLight(const Lighting& lighting, const EmbreeScene& scene)
    : SkyLight(lighting, scene.emitted_power(), scene_radius(scene.scene()), std::nullopt, scene.scene().lights) {}

float SkyLight::scene_radius(const Scene& scene) {
  const float r = 0.5f * scene.bounds().diagonal_length();
  return std::isfinite(r) ? r : 0.f;
}

SkyLight::SkyLight(const Lighting& lighting, double triangle_power, float scene_radius,
                   std::optional<float> fixed_share, std::span<const PunctualLight> lights) {
  from_outside_ = lit_from_outside(lighting, lights);
  float e_env = 0;  // irradiance the environment gives a surface facing it (luminance)
  if (lighting.environment && lighting.environment->strength > 0) {
    env_ = lighting.environment;
    rotation_ = env_->rotation_deg * (kPi / 180);
    if (env_->pixels) {
      const Image& img = *env_->pixels;
      w_ = img.width;
      h_ = img.height;
      weight_.resize(size_t(w_) * size_t(h_));
      std::vector<float> row_weight(static_cast<size_t>(h_));
      double sum_l = 0;  // luminance x solid angle over the sphere
      for (int y = 0; y < h_; ++y) {
        const float sin_theta = std::sin(kPi * (float(y) + 0.5f) / float(h_));
        double row = 0;
        for (int x = 0; x < w_; ++x) {
          const float wgt = luminance(img.rgb(x, y)) * sin_theta;
          weight_[size_t(y) * size_t(w_) + size_t(x)] = wgt;
          row += wgt;
        }
        row_weight[size_t(y)] = float(row);
        total_weight_ += row;
        columns_.emplace_back(std::span<const float>(&weight_[size_t(y) * size_t(w_)], size_t(w_)));
      }
      rows_ = DiscreteDistribution(row_weight);
      // Texel solid angle (2 pi / W) (pi / H) sin(theta): the mean radiance is sum / (4 pi).
      sum_l = total_weight_ * (2.0 * kPi / w_) * (kPi / h_);
      e_env = float(sum_l / (4 * kPi)) * kPi * env_->strength;
      if (!(total_weight_ > 0)) e_env = 0;
    } else {
      e_env = kPi * luminance(env_->color) * env_->strength;
    }
    if (!(e_env > 0)) env_.reset();
  }
  if (!env_) e_env = 0;
  // The suns: the lighting's and the directional lights, each with the irradiance it gives (luminance).
  std::vector<float> e_suns;
  const auto add_sun = [&](const SunLight& sun) {
    const float e = luminance(sun.irradiance);
    if (!(e > 0)) return;
    Sun s;
    s.frame = Frame::from_normal(normalize(sun.direction));
    const float sh = std::sin(0.5f * sun.angle_deg * (kPi / 180));
    s.sin2 = sh * sh;
    const float q = std::sin(0.25f * sun.angle_deg * (kPi / 180));
    s.one_minus_cos = 2 * q * q;  // 1 - cos(h) without cancellation
    s.l = sun.radiance();
    suns_.push_back(s);
    e_suns.push_back(e);
  };
  if (lighting.sun) add_sun(*lighting.sun);
  std::vector<double> punctual_power;
  for (const PunctualLight& l : lights) {
    if (l.type == LightType::kDirectional) {
      add_sun(l.as_sun());
    } else if (const double power = l.power(); power > 0) {
      punctual_.push_back(l);
      punctual_power.push_back(power);
    }
  }
  double e_sun = 0;
  for (float e : e_suns) e_sun += e;
  // The sky's power through the scene's bounding sphere: its irradiance on a disc of the sphere's
  // cross-section facing it. (For the split between the sky and the point lights a degenerate scene
  // counts as 1 mm across.)
  const double disc = kPi * double(scene_radius) * double(scene_radius);
  sky_power_ = (double(e_env) + e_sun) * disc;
  double other_power = sky_power_;
  for (double w : punctual_power) other_power += w;
  const bool others = e_env + e_sun > 0 || !punctual_.empty();
  triangle_power_ = triangle_power > 0 ? triangle_power : 0;
  p_tri_ = !(triangle_power_ > 0) ? 0.f
           : !others              ? 1.f
           : fixed_share          ? std::clamp(*fixed_share, 0.f, 1.f)
                                  : triangle_share_for_power(triangle_power_, other_power);
  if (!others) return;
  // The others' weights: the sky lights' powers and the point lights' (as above).
  const double sky_disc = std::max(disc, kPi * 2.5e-7);
  double total = (double(e_env) + e_sun) * sky_disc;
  for (double w : punctual_power) total += w;
  const double rest = 1.0 - double(p_tri_);
  p_env_ = float(rest * double(e_env) * sky_disc / total);
  for (size_t i = 0; i < suns_.size(); ++i) {
    suns_[i].p = float(rest * double(e_suns[i]) * sky_disc / total);
    p_sun_ += suns_[i].p;
  }
  for (double w : punctual_power) {
    p_punctual_each_.push_back(float(rest * w / total));
    p_punctual_ += p_punctual_each_.back();
  }
}

bool SkyLight::picks_sky(float u_select, float* u) const {
  if (u_select < p_tri_) {
    *u = std::min(u_select / p_tri_, 0.99999994f);
    return false;
  }
  *u = p_tri_ < 1 ? std::min((u_select - p_tri_) / (1 - p_tri_), 0.99999994f) : 0.f;
  return true;
}

SkyLight::Sample SkyLight::sample(float u, Vec2 u_dir, const Vec3& n, const Vec3& p) const {
  Sample s;
  const float p_sky = p_env_ + p_sun_ + p_punctual_;
  if (!(p_sky > 0)) return s;
  float x = u * p_sky;  // walks down the lights' probabilities
  if (env_ && x < p_env_) {
    if (!env_->pixels) {
      s.wi = Frame::from_normal(n).to_world(sample_cosine_hemisphere(u_dir));
    } else {
      float pmf, ry, rx;
      const size_t y = rows_.sample(u_dir.y, &pmf, &ry);
      const size_t col = columns_[y].sample(u_dir.x, &pmf, &rx);
      s.wi = equirect_to_direction({(float(col) + rx) / float(w_), (float(y) + ry) / float(h_)}, rotation_);
    }
    s.radiance = env_radiance(s.wi);
    s.pdf = pdf_environment(s.wi, n);
    return s;
  }
  x -= p_env_;
  const auto sample_sun = [&](const Sun& sun) {
    // Uniform in the cone: cos = 1 - u (1 - cos h).
    const float cos_t = 1 - u_dir.x * sun.one_minus_cos;
    const float sin_t = std::sqrt(std::max(0.f, u_dir.x * sun.one_minus_cos * (2 - u_dir.x * sun.one_minus_cos)));
    const float phi = 2 * kPi * u_dir.y;
    s.wi = sun.frame.to_world({sin_t * std::cos(phi), sin_t * std::sin(phi), cos_t});
    s.radiance = sun.l;
    s.pdf = sun.pdf();
    return s;
  };
  for (const Sun& sun : suns_) {
    if (x < sun.p) return sample_sun(sun);
    x -= sun.p;
  }
  if (punctual_.empty()) return suns_.empty() ? s : sample_sun(suns_.back());  // (rounding)
  size_t i = 0;
  while (i + 1 < punctual_.size() && x >= p_punctual_each_[i]) x -= p_punctual_each_[i++];
  const PunctualLight& l = punctual_[i];
  const Vec3 to = l.position - p;
  const float d2 = dot(to, to);
  if (!(d2 > 0)) return s;
  s.distance = std::sqrt(d2);
  s.wi = to / s.distance;
  s.radiance = l.intensity_towards(-s.wi) / d2;
  s.pdf = p_punctual_each_[i];
  s.delta = true;
  return s;
}

Vec3 SkyLight::env_radiance(const Vec3& d) const { return env_ ? env_->radiance(d) : Vec3(0.f); }

bool SkyLight::Sun::contains(const Vec3& d) const {
  if (!(dot(d, frame.n) > 0)) return false;
  const Vec3 c = cross(d, frame.n);
  return dot(c, c) <= sin2;
}

Vec3 SkyLight::sun_radiance(const Vec3& d) const {
  Vec3 out(0.f);
  for (const Sun& sun : suns_)
    if (sun.contains(d)) out += sun.l;
  return out;
}

Vec3 SkyLight::radiance(const Vec3& d) const { return env_radiance(d) + sun_radiance(d); }

Vec3 SkyLight::escaped(const Vec3& d, const Vec3& n, float pdf_bsdf) const {
  Vec3 out(0.f);
  if (env_) out += env_radiance(d) * power_heuristic(pdf_bsdf, pdf_environment(d, n));
  for (const Sun& sun : suns_)
    if (sun.contains(d)) out += sun.l * power_heuristic(pdf_bsdf, sun.pdf());
  return out;
}

float SkyLight::pdf_environment(const Vec3& d, const Vec3& n) const {
  if (!env_) return 0;
  if (!env_->pixels) return p_env_ * cosine_hemisphere_pdf(dot(d, n));
  const float sin_theta = std::sqrt(d.x * d.x + d.z * d.z);  // precise near the poles, unlike 1 - y^2
  if (!(sin_theta > 0)) return 0;
  const Vec2 ut = direction_to_equirect(d, rotation_);
  const int x = std::clamp(int(ut.x * float(w_)), 0, w_ - 1);
  const int y = std::clamp(int(ut.y * float(h_)), 0, h_ - 1);
  const double p_ut = double(weight_[size_t(y) * size_t(w_) + size_t(x)]) / total_weight_ * double(w_) * double(h_);
  return p_env_ * float(p_ut / (2.0 * kPi * kPi * sin_theta));
}

float SkyLight::pdf_sun(const Vec3& d) const {
  float pdf = 0;
  for (const Sun& sun : suns_)
    if (sun.contains(d)) pdf += sun.pdf();
  return pdf;
}

Vec3 sky_next_event(const SkyLight& sky, const EmbreeScene& scene, const Bsdf& bsdf, const Vec3& n, const Vec3& origin,
                    float u, Vec2 u_dir, bool mis, uint64_t* rays, Vec3* diffuse) {
  const SkyLight::Sample s = sky.sample(u, u_dir, n, origin);
  if (!(s.pdf > 0) || is_black(s.radiance)) return Vec3(0.f);
  const float cos_x = dot(n, s.wi);
  if (!(cos_x > 0)) return Vec3(0.f);
  const Vec3 f = bsdf.eval(s.wi);
  if (is_black(f)) return Vec3(0.f);
  ++*rays;
  // Towards a point light the ray ends just short of it (Embree's far distance along the unit wi).
  const float far = s.delta ? s.distance * (1 - 1e-5f) : std::numeric_limits<float>::infinity();
  if (scene.occluded(origin, s.wi, 0.f, far)) return Vec3(0.f);
  // A delta light has no BSDF-sampling technique: next event estimation's weight is 1.
  const float w = mis && !s.delta ? power_heuristic(s.pdf, bsdf.pdf(s.wi)) : 1.f;
  const float k = w * cos_x / s.pdf;
  if (diffuse) *diffuse = bsdf.eval_diffuse(s.wi) * s.radiance * k;
  return f * s.radiance * k;
}

}  // namespace epr
