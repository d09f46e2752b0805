// Frame windows: window_run.h.
#include "master/server/window_run.h"

#include <fmt/format.h>
#include <google/protobuf/util/message_differencer.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>

#include "common/limits.h"
#include "epr/v1/job_service.pb.h"
#include "wire/convert.h"

namespace epr {

bool WindowRun::cut_between(uint32_t a, uint32_t b) const {
  if (a > b) std::swap(a, b);
  for (size_t i = 0; i < cut.size(); ++i)
    if (cut[i] && measured[i] >= a && measured[i + 1] <= b) return true;
  return false;
}

std::vector<std::shared_ptr<Job>> WindowRun::neighbours(uint32_t frame) const {
  std::vector<std::shared_ptr<Job>> out;
  for (const auto& j : frames) {
    const uint32_t g = j->request.batch.frame.value_or(0);
    if (g != frame && (g > frame ? g - frame : frame - g) <= window && !cut_between(frame, g)) out.push_back(j);
  }
  return out;
}

std::pair<uint32_t, uint32_t> WindowRun::fed_by(uint32_t frame) const {
  std::pair<uint32_t, uint32_t> out{frame, frame};
  for (const auto& j : neighbours(frame)) {
    const uint32_t g = j->request.batch.frame.value_or(0);
    out = {std::min(out.first, g), std::max(out.second, g)};
  }
  return out;
}

std::pair<double, double> WindowRun::shares_of(uint32_t frame) const {
  std::pair<double, double> out{-1, -1};
  for (size_t i = 0; i < share.size(); ++i) {
    if (measured[i + 1] == frame) out.first = share[i];
    if (measured[i] == frame) out.second = share[i];
  }
  return out;
}

uint32_t window_sample_weight(uint32_t distance, float halving) {
  if (halving <= 0) return kWindowUnit;
  const double w = std::round(double(kWindowUnit) * std::exp2(-double(distance) / double(halving)));
  return uint32_t(std::clamp(w, 1.0, double(kWindowUnit)));
}

BatchMembership batch_from_spec(const v1::JobSpec& spec) {
  BatchMembership b{spec.batch_id(), spec.batch_name(),
                    spec.has_frame() ? std::optional<uint32_t>(spec.frame()) : std::nullopt, spec.batch_frames()};
  b.window = spec.frame_window();
  b.window_first = spec.window_first();
  b.window_last = spec.window_last();
  b.window_halving = spec.window_halving();
  return b;
}

void batch_to_spec(const BatchMembership& b, v1::JobSpec* spec) {
  spec->set_batch_id(b.id);
  spec->set_batch_name(b.name);
  if (b.frame) spec->set_frame(*b.frame);
  spec->set_batch_frames(b.frames);
  spec->set_frame_window(b.window);
  spec->set_window_first(b.window_first);
  spec->set_window_last(b.window_last);
  spec->set_window_halving(b.window_halving);
}

bool same_run(const BatchMembership& a, const BatchMembership& b) {
  return windowed(a) && windowed(b) && a.id == b.id && a.window == b.window && a.window_first == b.window_first &&
         a.window_last == b.window_last && a.window_halving == b.window_halving;
}

std::optional<std::string> window_error(const JobRequest& r) {
  const BatchMembership& b = r.batch;
  if (!windowed(b)) {
    if (b.window_first || b.window_last || b.window_halving != 0)
      return std::string("window_first, window_last and window_halving need a frame_window");
    return std::nullopt;
  }
  if (auto err = limits::kFrameWindow.check(int(std::min<uint32_t>(b.window, 1u << 30)))) return err;
  if (b.id.empty() || !b.frame) return std::string("a frame window needs a batch_id and a frame");
  if (!(b.window_halving >= 0 && b.window_halving <= float(limits::kFrameWindow.hi)))
    return fmt::format("window_halving {} is not between 0 and {} frames", b.window_halving, limits::kFrameWindow.hi);
  if (b.window_first > b.window_last || *b.frame < b.window_first || *b.frame > b.window_last)
    return fmt::format("frame {} is not inside its window run, frames {} to {}", *b.frame, b.window_first,
                       b.window_last);
  if (auto err = limits::kWindowRunFrames.check(int(std::min<uint32_t>(run_length(b), 1u << 30))))
    return fmt::format("frame {}: a window run of frames {} to {}: {}", *b.frame, b.window_first, b.window_last, *err);
  if (r.options.mode == RenderMode::kPathTrace)
    return fmt::format("frame {}: a frame window needs reprojection (mode skip or rp): pt traces no vertices",
                       *b.frame);
  if (r.options.reproject == ReprojectMethod::kExact)
    return fmt::format(
        "frame {}: a frame window needs --reproject gl or cpu: exact mode's samples are found visible from one "
        "camera only",
        *b.frame);
  return std::nullopt;
}

std::optional<std::string> run_mismatch(const JobRequest& r, const std::string& scene_hash, const Job& member) {
  const uint32_t frame = r.batch.frame.value_or(0), other = member.request.batch.frame.value_or(0);
  if (frame == other)
    return fmt::format("frame {} of window run {}..{} of batch {} is already on this master (job {})", frame,
                       r.batch.window_first, r.batch.window_last, r.batch.id, member.id);
  if (scene_hash != member.scene_hash)
    return fmt::format(
        "frame {}: its scene (content hash {:.12}) differs from frame {}'s ({:.12}, job {}): a window run renders one "
        "still scene (only the camera moves)",
        frame, scene_hash, other, member.scene_hash, member.id);
  // Every setting but the camera and the seed (frames trace paths of their own): the specs as the
  // wire carries them, without camera, seed and scene.
  auto settings = [](const JobRequest& q) {
    v1::JobSpec s = to_job_spec(q.options, SceneBundleData{}, q.camera);
    s.clear_camera();
    s.clear_seed();
    s.clear_scene();
    return s;
  };
  const v1::JobSpec a = settings(r), b = settings(member.request);
  std::string diff;
  google::protobuf::util::MessageDifferencer d;
  d.ReportDifferencesToString(&diff);
  if (d.Compare(b, a)) return std::nullopt;
  while (!diff.empty() && diff.back() == '\n') diff.pop_back();
  return fmt::format("frame {}: its settings differ from frame {}'s (job {}) in its window run: {}", frame, other,
                     member.id, diff);
}

}  // namespace epr
