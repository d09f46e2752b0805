#include "common/address.h"

#include <fmt/format.h>

#include <stdexcept>

namespace epr {
namespace {

bool host_char(char c) {
  return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '-' || c == '.' || c == '_';
}

std::optional<HostPort> fail(std::string* why, std::string reason) {
  if (why) *why = std::move(reason);
  return std::nullopt;
}

}  // namespace

std::optional<HostPort> parse_address(const std::string& text, AddressRules rules, std::string* why) {
  HostPort out;
  std::string port_text;
  if (!text.empty() && text.front() == '[') {
    const size_t close = text.find(']');
    if (close == std::string::npos) return fail(why, "no ']' after the IPv6 address");
    out.host = text.substr(1, close - 1);
    if (out.host.empty() || out.host.find_first_not_of("0123456789abcdefABCDEF:.%") != std::string::npos ||
        out.host.find(':') == std::string::npos)
      return fail(why, fmt::format("'{}' is not an IPv6 address", out.host));
    if (close + 1 >= text.size() || text[close + 1] != ':') return fail(why, "no :PORT after the address");
    port_text = text.substr(close + 2);
  } else {
    const size_t colon = text.rfind(':');
    if (colon == std::string::npos) return fail(why, "expected HOST:PORT");
    out.host = text.substr(0, colon);
    port_text = text.substr(colon + 1);
    if (out.host.find(':') != std::string::npos) return fail(why, "an IPv6 address goes in brackets: [ADDRESS]:PORT");
    if (out.host.empty() && !rules.empty_host) return fail(why, "no host before the port");
    for (char c : out.host)
      if (!host_char(c)) return fail(why, fmt::format("'{}' is not a host name or address", out.host));
  }
  if (port_text.empty()) return fail(why, "no port");
  if (port_text.find_first_not_of("0123456789") != std::string::npos)
    return fail(why, fmt::format("port '{}' is not a number", port_text));
  // Leading zeros are dropped before the size check: "0080" is 80, "1000000000000" is too large.
  const size_t first = port_text.find_first_not_of('0');
  const std::string digits = first == std::string::npos ? "0" : port_text.substr(first);
  const int lowest = rules.port_zero ? 0 : 1;
  if (digits.size() > 5 || std::stoi(digits) > 65535 || std::stoi(digits) < lowest)
    return fail(why, fmt::format("port {} is outside {}-65535", digits, lowest));
  out.port = std::stoi(digits);
  return out;
}

HostPort require_address(const std::string& flag, const std::string& text, AddressRules rules) {
  std::string why;
  if (auto a = parse_address(text, rules, &why)) return *a;
  throw std::invalid_argument(fmt::format("{} '{}': {}", flag, text, why));
}

std::string format_host_port(const HostPort& a) {
  return a.host.find(':') != std::string::npos ? fmt::format("[{}]:{}", a.host, a.port)
                                               : fmt::format("{}:{}", a.host, a.port);
}

}  // namespace epr
