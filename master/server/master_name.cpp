#include "master/server/master_name.h"

#include <fmt/format.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <stdexcept>

#include "common/address.h"

namespace epr {
namespace fs = std::filesystem;
namespace {

constexpr size_t kMaxName = 40;
constexpr const char* kFile = "master-name";

bool name_char(char c) {
  return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' || c == '-';
}

// The host name's first label with other characters as '-', cut so that `suffix` fits.
std::string host_part(size_t suffix) {
  char buf[256] = {};
  std::string host = ::gethostname(buf, sizeof buf - 1) == 0 ? buf : "";
  host = host.substr(0, host.find('.'));
  for (char& c : host)
    if (!name_char(c)) c = '-';
  if (host.empty()) host = "master";
  if (host.size() + suffix > kMaxName) host.resize(kMaxName - suffix);
  return host;
}

std::string made_name(int port) {
  if (port > 0) {
    const std::string p = fmt::format("-{}", port);
    return host_part(p.size()) + p;
  }
  std::random_device rd;
  const std::string r = fmt::format("-{:06x}", rd() & 0xffffff);
  return host_part(r.size()) + r;
}

void save(const fs::path& path, const std::string& name) {
  const fs::path tmp = path.string() + ".tmp";
  {
    std::ofstream f(tmp, std::ios::trunc);
    f << name << "\n";
    f.flush();
    if (!f) throw std::runtime_error(fmt::format("cannot write {}", tmp.string()));
  }
  std::error_code ec;
  fs::rename(tmp, path, ec);
  if (ec) throw std::runtime_error(fmt::format("cannot write {}: {}", path.string(), ec.message()));
}

}  // namespace

bool is_valid_master_name(const std::string& name) {
  if (name.empty() || name.size() > kMaxName) return false;
  for (char c : name)
    if (!name_char(c)) return false;
  return true;
}

std::string choose_master_name(const std::string& flag, const std::string& state_dir, int port) {
  if (!flag.empty() && !is_valid_master_name(flag))
    throw std::invalid_argument(
        fmt::format("--name '{}': a master name is 1 to {} of A-Z a-z 0-9 _ - (no dots)", flag, kMaxName));
  if (state_dir.empty()) return flag.empty() ? made_name(port) : flag;
  const fs::path path = fs::path(state_dir) / kFile;
  std::string saved;
  if (std::ifstream f(path); f) {
    std::getline(f, saved);
    if (!saved.empty() && saved.back() == '\r') saved.pop_back();
    if (flag.empty() && !saved.empty() && !is_valid_master_name(saved))
      throw std::invalid_argument(fmt::format("{} holds '{}', not a master name", path.string(), saved));
  }
  const std::string name = !flag.empty() ? flag : !saved.empty() ? saved : made_name(port);
  if (name != saved) save(path, name);
  return name;
}

int listen_port(const std::string& listen) {
  const auto a = parse_address(listen, {.port_zero = true, .empty_host = true});
  return a ? a->port : 0;
}

}  // namespace epr
