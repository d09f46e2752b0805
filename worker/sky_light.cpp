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
    : SkyLight(lighting, scene.emitted_power(), scene_radius(scene.scene())) {}

float SkyLight::scene_radius(const Scene& scene) {
  const float r = 0.5f * scene.bounds().diagonal_length();
  return std::isfinite(r) ? r : 0.f;
}

SkyLight::SkyLight(const Lighting& lighting, double triangle_power, float scene_radius,
                   std::optional<float> fixed_share) {
  float e_env = 0, e_sun = 0;  // irradiance each gives a surface facing it (luminance)
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
  if (lighting.sun && !is_black(lighting.sun->irradiance)) {
    sun_ = lighting.sun;
    sun_frame_ = Frame::from_normal(normalize(sun_->direction));
    const float sh = std::sin(0.5f * sun_->angle_deg * (kPi / 180));
    sun_sin2_ = sh * sh;
    const float s = std::sin(0.25f * sun_->angle_deg * (kPi / 180));
    sun_one_minus_cos_ = 2 * s * s;  // 1 - cos(h) without cancellation
    sun_l_ = sun_->radiance();
    e_sun = luminance(sun_->irradiance);
    if (!(e_sun > 0)) sun_.reset();
  }
  if (!env_) e_env = 0;
  if (!sun_) e_sun = 0;
  const bool sky = e_env + e_sun > 0;
  // The sky's power through the scene's bounding sphere: its irradiance on a disc of the sphere's
  // cross-section facing it.
  sky_power_ = double(e_env + e_sun) * kPi * double(scene_radius) * double(scene_radius);
  triangle_power_ = triangle_power > 0 ? triangle_power : 0;
  p_tri_ = !(triangle_power_ > 0) ? 0.f
           : !sky                 ? 1.f
           : fixed_share          ? std::clamp(*fixed_share, 0.f, 1.f)
                                  : triangle_share_for_power(triangle_power_, sky_power_);
  if (sky) {
    p_env_ = (1 - p_tri_) * e_env / (e_env + e_sun);
    p_sun_ = (1 - p_tri_) - p_env_;
    if (!sun_) p_sun_ = 0;
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

SkyLight::Sample SkyLight::sample(float u, Vec2 u_dir, const Vec3& n) const {
  Sample s;
  const float p_sky = p_env_ + p_sun_;
  if (!(p_sky > 0)) return s;
  if (env_ && u * p_sky < p_env_) {
    if (!env_->pixels) {
      s.wi = Frame::from_normal(n).to_world(sample_cosine_hemisphere(u_dir));
    } else {
      float pmf, ry, rx;
      const size_t y = rows_.sample(u_dir.y, &pmf, &ry);
      const size_t x = columns_[y].sample(u_dir.x, &pmf, &rx);
      s.wi = equirect_to_direction({(float(x) + rx) / float(w_), (float(y) + ry) / float(h_)}, rotation_);
    }
    s.radiance = env_radiance(s.wi);
    s.pdf = pdf_environment(s.wi, n);
    return s;
  }
  if (!sun_) return s;
  // Uniform in the cone: cos = 1 - u (1 - cos h).
  const float cos_t = 1 - u_dir.x * sun_one_minus_cos_;
  const float sin_t = std::sqrt(std::max(0.f, u_dir.x * sun_one_minus_cos_ * (2 - u_dir.x * sun_one_minus_cos_)));
  const float phi = 2 * kPi * u_dir.y;
  s.wi = sun_frame_.to_world({sin_t * std::cos(phi), sin_t * std::sin(phi), cos_t});
  s.radiance = sun_l_;
  s.pdf = p_sun_ / (2 * kPi * sun_one_minus_cos_);
  return s;
}

Vec3 SkyLight::env_radiance(const Vec3& d) const { return env_ ? env_->radiance(d) : Vec3(0.f); }

bool SkyLight::in_sun(const Vec3& d) const {
  if (!sun_ || !(dot(d, sun_frame_.n) > 0)) return false;
  const Vec3 c = cross(d, sun_frame_.n);
  return dot(c, c) <= sun_sin2_;
}

Vec3 SkyLight::sun_radiance(const Vec3& d) const { return in_sun(d) ? sun_l_ : Vec3(0.f); }

Vec3 SkyLight::radiance(const Vec3& d) const { return env_radiance(d) + sun_radiance(d); }

Vec3 SkyLight::escaped(const Vec3& d, const Vec3& n, float pdf_bsdf) const {
  Vec3 out(0.f);
  if (env_) out += env_radiance(d) * power_heuristic(pdf_bsdf, pdf_environment(d, n));
  const Vec3 ls = sun_radiance(d);
  if (!is_black(ls)) out += ls * power_heuristic(pdf_bsdf, pdf_sun(d));
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

float SkyLight::pdf_sun(const Vec3& d) const { return in_sun(d) ? p_sun_ / (2 * kPi * sun_one_minus_cos_) : 0.f; }

Vec3 sky_next_event(const SkyLight& sky, const EmbreeScene& scene, const Bsdf& bsdf, const Vec3& n, const Vec3& origin,
                    float u, Vec2 u_dir, bool mis, uint64_t* rays) {
  const SkyLight::Sample s = sky.sample(u, u_dir, n);
  if (!(s.pdf > 0) || is_black(s.radiance)) return Vec3(0.f);
  const float cos_x = dot(n, s.wi);
  if (!(cos_x > 0)) return Vec3(0.f);
  const Vec3 f = bsdf.eval(s.wi);
  if (is_black(f)) return Vec3(0.f);
  ++*rays;
  if (scene.occluded(origin, s.wi, 0.f, std::numeric_limits<float>::infinity())) return Vec3(0.f);
  const float w = mis ? power_heuristic(s.pdf, bsdf.pdf(s.wi)) : 1.f;
  return f * s.radiance * (w * cos_x / s.pdf);
}

}  // namespace epr
