"""A list of masters, as `epr --master` and `epr-worker --master` take it (wire/rpc/master_list.h).

Comma-separated gRPC targets, each HOST:PORT, [IPV6]:PORT, dns:///HOST:PORT (dns:HOST:PORT), or a
target gRPC takes as is (ipv4:, ipv6:, unix:). A host name that resolves to several addresses is one
master per address (a Kubernetes headless Service names every master pod), connected by address and,
with TLS, checked against the name. IPv4 addresses when the name has any, else IPv6 ones, so
localhost (A and AAAA records of one host) is one master. A name with one address, or none (yet),
stays one master on the name itself, which its channel resolves as gRPC always does.
"""

from __future__ import annotations

import ipaddress
import re
import socket
from dataclasses import dataclass
from typing import Callable, Iterable, List, Optional, Union

from .errors import ArgumentError

_GRPC_SCHEMES = ("ipv4:", "ipv6:", "unix:", "unix-abstract:", "vsock:")

# A host name's addresses (numeric, no port), or None when it does not resolve.
Resolver = Callable[[str], Optional[List[str]]]


@dataclass(frozen=True)
class MasterEndpoint:
    """One master: the channel's target, how messages name it, and the name its certificate is checked
    against when connected by address ("" for the target's own host)."""

    target: str
    name: str
    tls_server_name: str = ""


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
        return True
    except ValueError:
        return False


def _check_port(spec: str, port: str) -> None:
    if not re.fullmatch(r"[0-9]+", port):
        raise ArgumentError(f"master: '{spec}' has no numeric port")
    if not 1 <= int(port) <= 65535:
        raise ArgumentError(f"master: '{spec}' has port {int(port)}, outside 1-65535")


def _parse_one(entry: str):
    """(spec, host, port): host "" for a target gRPC takes as is. ArgumentError when malformed."""
    spec = entry.strip(" \t\n")
    if not spec:
        raise ArgumentError("master: an empty entry in the list")
    rest = spec
    if rest.startswith("dns:"):
        rest = rest[4:]
        if rest.startswith("//"):  # dns://[authority]/host:port: the authority (a DNS server) is not used
            slash = rest.find("/", 2)
            if slash < 0:
                raise ArgumentError(f"master: '{spec}' has no host")
            rest = rest[slash + 1 :]
    elif rest.startswith(("ipv4:", "ipv6:")):  # ADDRESS:PORT, [ADDRESS]:PORT; without a port gRPC takes 443
        rest = rest[5:]
        if rest.count(":") == 1 or "]:" in rest:
            _check_port(spec, rest.rpartition(":")[2])
        return spec, "", ""
    elif rest.startswith(_GRPC_SCHEMES):
        return spec, "", ""
    if rest.startswith("["):  # [IPV6]:PORT
        bracket = rest.find("]")
        if bracket < 0 or rest[bracket + 1 : bracket + 2] != ":":
            raise ArgumentError(f"master: '{spec}' is not [IPV6]:PORT")
        _check_port(spec, rest[bracket + 2 :])
        return spec, "", ""
    host, colon, port = rest.rpartition(":")
    if not colon or not host or not port:
        raise ArgumentError(f"master: '{spec}' is not HOST:PORT")
    _check_port(spec, port)
    if _is_ip(host) or ":" in host:
        return spec, "", ""
    return spec, host, port


def resolve_host(host: str) -> Optional[List[str]]:
    """getaddrinfo: the host's IPv4 addresses if it has any, else its IPv6 ones; sorted, unique."""
    try:
        infos = socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError):
        return None
    v4 = sorted({i[4][0] for i in infos if i[0] == socket.AF_INET})
    v6 = sorted({i[4][0] for i in infos if i[0] == socket.AF_INET6})
    return v4 or v6


def master_endpoints(masters: Union[str, Iterable[str]], resolver: Optional[Resolver] = None) -> List[MasterEndpoint]:
    """One endpoint per master of `masters` (a comma-separated string, or a list of such strings),
    deduplicated by target in list order. ArgumentError (a ValueError) for an empty or malformed entry."""
    text = masters if isinstance(masters, str) else ",".join(masters)
    out: List[MasterEndpoint] = []
    seen = set()

    def add(e: MasterEndpoint) -> None:
        if e.target not in seen:
            seen.add(e.target)
            out.append(e)

    for spec, host, port in [_parse_one(entry) for entry in text.split(",")]:
        addresses = (resolver or resolve_host)(host) if host else None
        if not addresses or len(addresses) <= 1:
            add(MasterEndpoint(spec, spec))  # the channel resolves the name itself
            continue
        for a in sorted(addresses):
            target = f"ipv6:[{a}]:{port}" if ":" in a else f"ipv4:{a}:{port}"
            add(MasterEndpoint(target, f"{host}:{port} ({a})", host))
    return out
