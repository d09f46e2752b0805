#include "wire/rpc/master_list.h"

#include <arpa/inet.h>
#include <fmt/format.h>
#include <netdb.h>
#include <sys/socket.h>

#include <algorithm>
#include <set>
#include <stdexcept>

#include "common/address.h"

namespace epr {
namespace {

std::string trim(const std::string& s) {
  const size_t a = s.find_first_not_of(" \t\n");
  if (a == std::string::npos) return "";
  return s.substr(a, s.find_last_not_of(" \t\n") - a + 1);
}

bool starts_with(const std::string& s, const char* prefix) { return s.rfind(prefix, 0) == 0; }

bool is_ip_literal(const std::string& host) {
  unsigned char buf[16];
  return inet_pton(AF_INET, host.c_str(), buf) == 1 || inet_pton(AF_INET6, host.c_str(), buf) == 1;
}

// The HOST:PORT part of an entry (common/address.h), or std::invalid_argument naming the entry.
HostPort address(const std::string& spec, const std::string& host_port) {
  std::string why;
  if (auto a = parse_address(host_port, {}, &why)) return *a;
  throw std::invalid_argument(fmt::format("--master '{}': {}", spec, why));
}

MasterTarget parse_one(const std::string& entry) {
  MasterTarget t;
  t.spec = trim(entry);
  if (t.spec.empty()) throw std::invalid_argument("--master: an empty entry in the list");
  std::string rest = t.spec;
  if (starts_with(rest, "dns:")) {
    rest = rest.substr(4);
    if (starts_with(rest, "//")) {  // dns://[authority]/host:port: the authority (a DNS server) is not used
      const size_t slash = rest.find('/', 2);
      if (slash == std::string::npos) throw std::invalid_argument(fmt::format("--master: '{}' has no host", t.spec));
      rest = rest.substr(slash + 1);
    }
  } else {
    for (const char* scheme : {"unix:", "unix-abstract:", "vsock:"})
      if (starts_with(rest, scheme)) return t;  // gRPC's own: taken as is
    for (const char* scheme : {"ipv4:", "ipv6:"})
      if (starts_with(rest, scheme)) {  // gRPC's own, one address: its port is checked
        address(t.spec, rest.substr(std::string(scheme).size()));
        return t;
      }
  }
  const HostPort a = address(t.spec, rest);
  if (starts_with(rest, "[") || is_ip_literal(a.host)) return t;  // an address: the channel's target as is
  const std::string host = a.host, port = std::to_string(a.port);
  t.host = host;
  t.port = port;
  return t;
}

}  // namespace

std::vector<MasterTarget> parse_master_list(const std::string& list) {
  std::vector<MasterTarget> out;
  size_t from = 0;
  for (;;) {
    const size_t comma = list.find(',', from);
    out.push_back(parse_one(list.substr(from, comma == std::string::npos ? std::string::npos : comma - from)));
    if (comma == std::string::npos) break;
    from = comma + 1;
  }
  return out;
}

std::optional<std::vector<std::string>> resolve_host(const std::string& host) {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* res = nullptr;
  if (getaddrinfo(host.c_str(), nullptr, &hints, &res) != 0) return std::nullopt;
  std::set<std::string> v4, v6;
  for (const addrinfo* a = res; a; a = a->ai_next) {
    char text[INET6_ADDRSTRLEN] = {};
    if (a->ai_family == AF_INET &&
        inet_ntop(AF_INET, &reinterpret_cast<const sockaddr_in*>(a->ai_addr)->sin_addr, text, sizeof text))
      v4.insert(text);
    else if (a->ai_family == AF_INET6 &&
             inet_ntop(AF_INET6, &reinterpret_cast<const sockaddr_in6*>(a->ai_addr)->sin6_addr, text, sizeof text))
      v6.insert(text);
  }
  freeaddrinfo(res);
  const std::set<std::string>& chosen = v4.empty() ? v6 : v4;
  return std::vector<std::string>(chosen.begin(), chosen.end());
}

std::vector<MasterEndpoint> resolve_masters(const std::vector<MasterTarget>& targets, const MasterResolver& resolver,
                                            bool* resolved) {
  if (resolved) *resolved = true;
  std::vector<MasterEndpoint> out;
  std::set<std::string> seen;
  auto add = [&](MasterEndpoint e) {
    if (seen.insert(e.target).second) out.push_back(std::move(e));
  };
  for (const MasterTarget& t : targets) {
    if (t.host.empty()) {
      add({t.spec, t.spec, ""});
      continue;
    }
    std::optional<std::vector<std::string>> addresses = resolver ? resolver(t.host) : resolve_host(t.host);
    if (!addresses && resolved) *resolved = false;
    if (!addresses || addresses->size() <= 1) {
      add({t.spec, t.spec, ""});  // the channel resolves the name itself
      continue;
    }
    std::vector<std::string> sorted = *addresses;
    std::sort(sorted.begin(), sorted.end());
    for (const std::string& a : sorted) {
      const bool v6 = a.find(':') != std::string::npos;
      add({v6 ? fmt::format("ipv6:[{}]:{}", a, t.port) : fmt::format("ipv4:{}:{}", a, t.port),
           fmt::format("{}:{} ({})", t.host, t.port, a), t.host});
    }
  }
  return out;
}

}  // namespace epr
