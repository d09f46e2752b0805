#include "wire/rpc/token.h"

#include <fmt/format.h>
#include <sys/stat.h>

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <fstream>
#include <sstream>

#include "common/log.h"

namespace epr::rpc {
namespace {

// `text` with trailing white space removed, if it is one token; `source` names the file or variable.
std::string check_token(std::string text, const std::string& source) {
  while (!text.empty() && std::isspace(static_cast<unsigned char>(text.back()))) text.pop_back();
  if (text.empty()) throw TokenError(fmt::format("{} is empty: it must hold the bearer token", source));
  if (!is_valid_token(text))
    throw TokenError(
        fmt::format("{} must hold one token of printable ASCII characters, without spaces or line breaks "
                    "(only trailing white space is ignored)",
                    source));
  return text;
}

}  // namespace

bool is_valid_token(std::string_view token) {
  return !token.empty() &&
         std::all_of(token.begin(), token.end(), [](unsigned char c) { return c > 0x20 && c < 0x7f; });
}

std::string read_token_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw TokenError(fmt::format("cannot read the token file '{}'", path));
  std::ostringstream ss;
  ss << in.rdbuf();
  if (in.bad()) throw TokenError(fmt::format("cannot read the token file '{}'", path));
  std::string token = check_token(ss.str(), fmt::format("the token file '{}'", path));
  struct stat st {};
  if (::stat(path.c_str(), &st) == 0 && (st.st_mode & (S_IRWXG | S_IRWXO)))
    logger("rpc")->warn("the token file '{}' is open to other users (mode {:03o}): chmod 600 it", path,
                        st.st_mode & 0777);
  return token;
}

std::optional<std::string> configured_token(const std::string& token_file) {
  if (!token_file.empty()) return read_token_file(token_file);
  const char* env = std::getenv("EPR_TOKEN");
  if (!env || !*env) return std::nullopt;
  return check_token(env, "$EPR_TOKEN");
}

}  // namespace epr::rpc
