// A list of masters, as `epr-worker --master` and `epr --master` take it: comma-separated gRPC
// targets, each HOST:PORT, [IPV6]:PORT, dns:///HOST:PORT (dns:HOST:PORT), or a target gRPC takes as
// is (ipv4:, ipv6:, unix:). A host name may resolve to several addresses, one master each (a
// Kubernetes headless Service names every master pod); resolve_masters() turns the list into one
// endpoint per master.
//
// Resolution (getaddrinfo, or a test's resolver): IPv4 addresses when the name has any, else IPv6
// ones, so a name with both an A and an AAAA record of one host (localhost) is one master, not two.
// A name that resolves to one address, or that does not resolve (yet), stays one endpoint on the name
// itself: its channel resolves it as gRPC always does (a single master behaves as it did before
// several were possible). A name with several addresses gives one endpoint per address, connected by
// address; with TLS, the certificate is checked against the name (tls_server_name).
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace epr {

/// One entry of the list.
struct MasterTarget {
  std::string spec;  // as written in the list (whitespace trimmed)
  std::string host;  // empty: a target gRPC takes as is (ipv4:, ipv6:, unix:, an IP literal)
  std::string port;
};

/// One master: the channel's target, how messages name it, and the name its certificate is checked
/// against when connected by address.
struct MasterEndpoint {
  std::string target;           // the channel's target; also the endpoint's identity
  std::string name;             // for messages: the spec, or "HOST:PORT (ADDRESS)"
  std::string tls_server_name;  // empty: the target's own host
  bool operator==(const MasterEndpoint& o) const {
    return target == o.target && name == o.name && tls_server_name == o.tls_server_name;
  }
};

/// A host name's addresses (numeric, no port), or nullopt when resolution failed.
using MasterResolver = std::function<std::optional<std::vector<std::string>>(const std::string& host)>;

/// Splits and checks --master. Throws std::invalid_argument naming the bad entry (empty entries, a
/// missing port).
std::vector<MasterTarget> parse_master_list(const std::string& list);

/// getaddrinfo: the host's addresses, IPv4 ones if it has any, else IPv6 ones; sorted, no duplicates.
std::optional<std::vector<std::string>> resolve_host(const std::string& host);

/// One endpoint per master (deduplicated by target, in list order). `resolved` (may be null) is set
/// false when some name did not resolve; its entry then stays an endpoint on the name.
std::vector<MasterEndpoint> resolve_masters(const std::vector<MasterTarget>& targets, const MasterResolver& resolver,
                                            bool* resolved = nullptr);

}  // namespace epr
