// Errors naming file and line, and the tokens and numbers of OBJ and MTL statements (text.h).
#include "common/scene_loader/text.h"

#include <fmt/format.h>

#include <charconv>
#include <cmath>
#include <exception>
#include <system_error>

#include "common/log.h"
#include "common/scene_error.h"

namespace epr::loader {

std::shared_ptr<spdlog::logger> scene_log() { return logger("common"); }

void warn(LoadReport& report, std::string message) {
  scene_log()->debug("scene warning: {}", message);
  report.warnings.push_back(std::move(message));
}

void fail(const std::string& file, size_t line, const std::string& reason) {
  if (line == 0) fail_file(file, reason);
  throw SceneError(fmt::format("{}:{}: {}", file, line, reason));
}

void fail_file(const std::string& file, const std::string& reason) {
  throw SceneError(fmt::format("{}: {}", file, reason));
}

void validate_or_fail(const Scene& scene, const std::string& file) {
  try {
    scene.validate();
  } catch (const std::exception& e) {
    fail_file(file, e.what());
  }
}

std::string_view strip_comment(std::string_view line) {
  for (size_t i = 0; i < line.size(); ++i)
    if (line[i] == '#' && (i == 0 || is_space(line[i - 1]))) {
      line = line.substr(0, i);
      break;
    }
  while (!line.empty() && is_space(line.front())) line.remove_prefix(1);
  while (!line.empty() && is_space(line.back())) line.remove_suffix(1);
  return line;
}

void tokenize(std::string_view line, std::vector<std::string_view>* tokens) {
  tokens->clear();
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && is_space(line[i])) ++i;
    const size_t start = i;
    while (i < line.size() && !is_space(line[i])) ++i;
    if (i > start) tokens->push_back(line.substr(start, i - start));
  }
}

std::string_view rest_after_keyword(std::string_view stripped, std::string_view keyword) {
  std::string_view rest = stripped.substr(keyword.size());
  while (!rest.empty() && is_space(rest.front())) rest.remove_prefix(1);
  return rest;
}

std::string quote_token(std::string_view token) {
  constexpr size_t kMax = 40;
  std::string s(token.substr(0, kMax));
  for (char& c : s)
    if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) c = '?';
  return "'" + s + (token.size() > kMax ? "...'" : "'");
}

float parse_real(std::string_view tok, double limit, const std::string& file, size_t line, const char* what) {
  std::string_view s = tok;
  if (s.size() > 1 && s[0] == '+' && s[1] != '-' && s[1] != '+') s.remove_prefix(1);
  double v = 0;
  const char* end = s.data() + s.size();
  const auto [ptr, ec] = std::from_chars(s.data(), end, v);
  if (ec == std::errc::result_out_of_range)
    fail(file, line, fmt::format("{} {} is out of range", what, quote_token(tok)));
  if (ec != std::errc() || ptr != end || s.empty())
    fail(file, line, fmt::format("bad number {} for {}", quote_token(tok), what));
  if (!std::isfinite(v)) fail(file, line, fmt::format("{} {} is not finite", what, quote_token(tok)));
  if (std::abs(v) > limit)
    fail(file, line, fmt::format("{} {} exceeds the magnitude limit {:g}", what, quote_token(tok), limit));
  return float(v);
}

std::vector<std::string> split_escaped(std::string_view s) {
  std::vector<std::string> out;
  std::string cur;
  bool escaping = false;
  for (char c : s) {
    if (escaping) {
      cur += c;
      escaping = false;
    } else if (c == '\\') {
      escaping = true;
    } else if (is_space(c)) {
      if (!cur.empty()) out.push_back(std::move(cur));
      cur.clear();
    } else {
      cur += c;
    }
  }
  if (!cur.empty()) out.push_back(std::move(cur));
  return out;
}

}  // namespace epr::loader
