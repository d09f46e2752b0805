#include "client/batch.h"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <random>
#include <set>
#include <stdexcept>

#include "common/camera_animation.h"
#include "common/limits.h"
#include "common/log.h"
#include "wire/convert.h"

namespace epr {
namespace {

constexpr size_t kMaxNameBytes = 256;  // JobSpec.name and batch_name

// A frame number of `part` ("12"), or std::invalid_argument.
uint32_t frame_number(const std::string& digits, const std::string& part) {
  if (digits.empty() || !std::all_of(digits.begin(), digits.end(), [](unsigned char c) { return std::isdigit(c); }))
    throw std::invalid_argument(fmt::format("--frames: '{}' is not a frame, a range A-B or A-BxSTEP", part));
  const size_t first = std::min(digits.find_first_not_of('0'), digits.size() - 1);  // leading zeros dropped
  if (digits.size() - first > 9)
    throw std::invalid_argument(
        fmt::format("--frames: '{}': the number {} is too large (at most {})", part, digits, kMaxFrame));
  const unsigned long v = std::stoul(digits.substr(first));
  if (v > kMaxFrame) throw std::invalid_argument(fmt::format("--frames: frame {} is over {}", v, kMaxFrame));
  return uint32_t(v);
}

std::string default_batch_name(const std::string& scene) {
  std::string n = scene.rfind("builtin:", 0) == 0 ? scene.substr(8) : std::filesystem::path(scene).stem().string();
  for (char& c : n)
    if (c == '?' || c == '&' || c == '=' || c == '/') c = '_';
  return n.empty() ? "frames" : n;
}

}  // namespace

std::vector<uint32_t> parse_frame_list(const std::string& text) {
  if (text.empty()) throw std::invalid_argument("--frames: empty (give e.g. 1-240, 1-240x2 or 1,5,9)");
  std::set<uint32_t> frames;
  size_t start = 0;
  while (start <= text.size()) {
    const size_t comma = std::min(text.find(',', start), text.size());
    const std::string part = text.substr(start, comma - start);
    start = comma + 1;
    const size_t dash = part.find('-');
    if (dash == std::string::npos) {
      frames.insert(frame_number(part, part));
    } else {
      const size_t x = part.find('x', dash);
      const uint32_t a = frame_number(part.substr(0, dash), part);
      const uint32_t b = frame_number(part.substr(dash + 1, x == std::string::npos ? x : x - dash - 1), part);
      const uint32_t step = x == std::string::npos ? 1 : frame_number(part.substr(x + 1), part);
      if (b < a) throw std::invalid_argument(fmt::format("--frames: range '{}' ends before it starts", part));
      if (step == 0) throw std::invalid_argument(fmt::format("--frames: range '{}' has step 0", part));
      if ((b - a) / step + 1 + frames.size() > kMaxBatchFrames)
        throw std::invalid_argument(fmt::format("--frames: more than {} frames", kMaxBatchFrames));
      for (uint64_t f = a; f <= b; f += step) frames.insert(uint32_t(f));
    }
    if (frames.size() > kMaxBatchFrames)
      throw std::invalid_argument(fmt::format("--frames: more than {} frames", kMaxBatchFrames));
    if (comma == text.size()) break;
  }
  return {frames.begin(), frames.end()};
}

std::string new_batch_id() {
  std::random_device rd;
  std::string s = "b-";
  for (int i = 0; i < 6; ++i) s += fmt::format("{:02x}", rd() & 0xff);
  return s;
}

bool valid_batch_id(const std::string& id) {
  return !id.empty() && id.size() <= 64 &&
         std::all_of(id.begin(), id.end(), [](unsigned char c) { return std::isalnum(c) || c == '_' || c == '-'; });
}

std::string frame_file_name(const std::string& prefix, uint32_t frame) {
  return fmt::format("{}.{:04d}", prefix, frame);
}

namespace {

// The window's checks, and the first and last frame of each frame's run (frames ascending).
std::vector<std::pair<uint32_t, uint32_t>> window_runs(const RenderOptions& opts, const std::vector<uint32_t>& frames,
                                                       const WindowOptions& w) {
  std::vector<std::pair<uint32_t, uint32_t>> runs(frames.size());
  if (w.frame_window == 0) {
    if (w.halving != 0) throw std::invalid_argument("--window-halving needs --frame-window");
    return runs;
  }
  if (!(w.halving >= 0 && w.halving <= float(limits::kFrameWindow.hi)))
    throw std::invalid_argument(
        fmt::format("--window-halving {} must be between 0 and {} frames", w.halving, limits::kFrameWindow.hi));
  if (auto err = limits::kFrameWindow.check(int(std::min<uint32_t>(w.frame_window, 1u << 30))))
    throw std::invalid_argument(*err);
  if (auto err = limits::kWindowRunFrames.check(int(std::min<uint32_t>(w.run, 1u << 30))))
    throw std::invalid_argument(*err);
  if (opts.mode == RenderMode::kPathTrace)
    throw std::invalid_argument("--frame-window needs reprojection (--mode skip or rp): pt traces no vertices");
  if (opts.reproject == ReprojectMethod::kExact)
    throw std::invalid_argument(
        "--frame-window needs --reproject gl or cpu: exact mode's samples are found visible from one camera only");
  for (size_t i = 0, start = 0; i < frames.size(); ++i) {
    if (i > start && (frames[i] != frames[i - 1] + 1 || i - start == w.run)) start = i;
    runs[i].first = frames[start];
    // Extended to each frame of the run as it grows.
    for (size_t j = start; j <= i; ++j) runs[j].second = frames[i];
  }
  return runs;
}

}  // namespace

FrameBatch plan_batch(const RenderOptions& opts, const SubmitOptions& submit, const std::vector<uint32_t>& frames,
                      std::string batch_id, const WindowOptions& window) {
  if (frames.empty()) throw std::invalid_argument("a batch needs at least one frame");
  if (frames.size() > kMaxBatchFrames)
    throw std::invalid_argument(fmt::format("a batch has at most {} frames", kMaxBatchFrames));
  FrameBatch batch;
  batch.id = batch_id.empty() ? new_batch_id() : std::move(batch_id);
  if (!valid_batch_id(batch.id))
    throw std::invalid_argument(fmt::format("batch id '{}' is not 1 to 64 of [A-Za-z0-9_-]", batch.id));
  batch.name = submit.name.empty() ? default_batch_name(opts.scene) : submit.name;
  if (batch.name.size() + 9 > kMaxNameBytes)
    throw std::invalid_argument(
        fmt::format("batch name is {} bytes long, at most {}", batch.name.size(), kMaxNameBytes - 9));
  batch.bundle = bundle_scene(opts.scene, opts.lighting, opts.env_folder, BundleLoad::kUpload);
  CameraSpec still;
  const CameraAnimation animation = load_camera_animation(opts.scene, {}, &still);
  if (!animation.animated())
    logger("client")->warn("{} has no camera animation: every frame of the batch renders the same view", opts.scene);

  // The frames' cameras are the job's explicit cameras: the overrides go in here, not in the spec.
  RenderOptions frame_opts = opts;
  frame_opts.eye.reset();
  frame_opts.look.reset();
  frame_opts.up.reset();
  frame_opts.fov.reset();
  batch.frames = frames;
  std::sort(batch.frames.begin(), batch.frames.end());
  batch.frames.erase(std::unique(batch.frames.begin(), batch.frames.end()), batch.frames.end());
  const auto runs = window_runs(opts, batch.frames, window);
  for (size_t i = 0; i < batch.frames.size(); ++i) {
    const uint32_t frame = batch.frames[i];
    if (auto problem = animation.frame_problem(frame, still)) throw SceneError(*problem);
    const CameraSpec camera = opts.camera_for(animation.at(frame, still));
    if (auto err = camera.validate())
      throw std::invalid_argument(fmt::format("frame {}: the camera with the overrides given: {}", frame, *err));
    v1::JobSpec spec = to_job_spec(frame_opts, SceneBundleData{}, camera);
    spec.clear_scene();
    spec.set_name(frame_file_name(batch.name, frame));
    spec.set_priority(submit.priority);
    if (submit.time_budget_seconds) spec.set_time_budget_seconds(*submit.time_budget_seconds);
    spec.set_request_id(fmt::format("{}-{}", batch.id, frame));
    spec.set_batch_id(batch.id);
    spec.set_batch_name(batch.name);
    spec.set_frame(frame);
    spec.set_batch_frames(uint32_t(batch.frames.size()));
    if (window.frame_window) {
      spec.set_frame_window(window.frame_window);
      spec.set_window_first(runs[i].first);
      spec.set_window_last(runs[i].second);
      spec.set_window_halving(window.halving);
      spec.set_seed(opts.seed + frame);
    }
    batch.specs.push_back(std::move(spec));
  }
  return batch;
}

v1::SceneBundle scene_for(JobClient& client, const SceneBundleData& bundle) {
  v1::SceneBundle scene;
  if (!bundle.builtin.empty())
    scene.set_builtin(bundle.builtin);
  else
    scene.set_uploaded_hash(client.upload_scene(bundle));
  return scene;
}

std::vector<std::string> submit_batch(JobClient& client, const FrameBatch& batch) {
  const v1::SceneBundle scene = scene_for(client, batch.bundle);
  std::vector<std::string> ids;
  for (v1::JobSpec spec : batch.specs) {
    *spec.mutable_scene() = scene;
    ids.push_back(client.submit(spec));
  }
  return ids;
}

std::vector<v1::JobStatus> list_batch(JobClient& client, const std::string& batch_id) {
  std::vector<v1::JobStatus> jobs = client.list({}, 0, batch_id);
  jobs.erase(std::remove_if(jobs.begin(), jobs.end(), [&](const v1::JobStatus& s) { return s.batch_id() != batch_id; }),
             jobs.end());
  std::stable_sort(jobs.begin(), jobs.end(),
                   [](const v1::JobStatus& a, const v1::JobStatus& b) { return a.frame() < b.frame(); });
  return jobs;
}

double job_progress(const v1::JobStatus& s) {
  if (s.state() == v1::JOB_STATE_DONE) return 1.0;
  if (s.state() != v1::JOB_STATE_RUNNING) return 0.0;
  const double target = std::max<uint32_t>(1, s.target_spp());
  double frac = s.rounds_planned() ? double(s.round()) / s.rounds_planned() : s.spp_mean() / target;
  if (s.effective().mode() == v1::RENDER_MODE_SKIP) frac = s.spp_min() / target;
  return std::clamp(frac, 0.0, 1.0);
}

BatchSummary summarize_batch(const std::vector<v1::JobStatus>& jobs) {
  BatchSummary b;
  double sum = 0;
  for (const auto& s : jobs) {
    if (b.id.empty()) b.id = s.batch_id();
    if (b.name.empty()) b.name = s.batch_name();
    b.frames = std::max(b.frames, s.batch_frames());
    switch (s.state()) {
      case v1::JOB_STATE_DONE:
        ++b.done;
        break;
      case v1::JOB_STATE_RUNNING:
        ++b.running;
        break;
      case v1::JOB_STATE_FAILED:
        ++b.failed;
        break;
      case v1::JOB_STATE_CANCELLED:
        ++b.cancelled;
        break;
      default:
        ++b.queued;
    }
    sum += job_progress(s);
  }
  b.frames = std::max<uint32_t>(b.frames, uint32_t(jobs.size()));
  b.progress = b.frames ? sum / b.frames : 0.0;
  return b;
}

}  // namespace epr
