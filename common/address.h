// Network addresses as every program takes them on its command line (epr --master, epr-worker
// --master, epr-master --listen and --http, epr render --http): HOST:PORT, [IPV6]:PORT, or a host
// name with a port. One parser, so that every program refuses the same things: a port outside
// 1-65535 (never taken modulo 65536), a missing or non-numeric port, an unbracketed IPv6 address.
#pragma once

#include <optional>
#include <string>

namespace epr {

struct HostPort {
  std::string host;  // without the brackets of [IPV6]; empty only when AddressRules::empty_host allowed it
  int port = 0;
};

struct AddressRules {
  bool port_zero = false;   // a listen address: port 0 picks a free port
  bool empty_host = false;  // ":PORT" (every interface of a listen address)
};

/// Parses `text`; on failure nullopt and the reason in *why ("port 112837 is outside 1-65535").
std::optional<HostPort> parse_address(const std::string& text, AddressRules rules = {}, std::string* why = nullptr);

/// parse_address, or std::invalid_argument "FLAG 'TEXT': REASON".
HostPort require_address(const std::string& flag, const std::string& text, AddressRules rules = {});

/// "HOST:PORT", with brackets around an IPv6 host.
std::string format_host_port(const HostPort& a);

}  // namespace epr
