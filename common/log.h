// One named spdlog logger per component ("common", "worker", "master", "client").
#pragma once

#include <spdlog/spdlog.h>

#include <memory>
#include <string>

namespace epr {

/// The component's logger, created on first use and writing to stderr.
std::shared_ptr<spdlog::logger> logger(const std::string& component);
/// Sets every logger's level from "trace", "debug", "info", "warn", "error" or "off".
void set_log_level(const std::string& level);

}  // namespace epr
