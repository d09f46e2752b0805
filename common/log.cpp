#include "common/log.h"

#include <spdlog/sinks/stdout_color_sinks.h>

#include <mutex>

namespace epr {

std::shared_ptr<spdlog::logger> logger(const std::string& component) {
  // Makes the look-up and the creation one step (spdlog throws when a name is registered twice). It
  // guards no field, only this call, so it stays a plain std::mutex with nothing to annotate.
  static std::mutex mu;
  std::lock_guard lock(mu);
  if (auto l = spdlog::get(component)) return l;
  auto l = spdlog::stderr_color_mt(component);
  l->set_level(spdlog::get_level());
  return l;
}

void set_log_level(const std::string& level) {
  const auto lvl = spdlog::level::from_str(level);
  spdlog::set_level(lvl);
  spdlog::apply_all([lvl](std::shared_ptr<spdlog::logger> l) { l->set_level(lvl); });
}

}  // namespace epr
