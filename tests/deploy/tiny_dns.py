#!/usr/bin/python3
"""A minimal authoritative DNS server over UDP, standing in for Docker's embedded DNS in
netns_cluster_test.sh: service names resolve by DNS, as in a compose network.

    tiny_dns.py BIND_ADDRESS NAME=IPV4[,IPV4...] [NAME=...]

Answers A queries for the given names (every address of a name, as compose's DNS answers a network
alias that several containers share), an empty NOERROR for their other types (AAAA, ...), and
NXDOMAIN for any other name, so resolvers never wait for a server that is not there. (gRPC's default
c-ares resolver asks DNS before /etc/hosts, so a hosts file alone makes each lookup take seconds.)
Prints "ready" once bound; runs until killed.
"""
import socket
import struct
import sys


def read_name(data, offset):
    labels = []
    while True:
        n = data[offset]
        offset += 1
        if n == 0:
            return ".".join(labels), offset
        if n & 0xC0:  # compression pointers do not occur in questions
            raise ValueError("compressed name in a question")
        labels.append(data[offset : offset + n].decode("ascii", "replace"))
        offset += n


def answer(query, records):
    ident, flags, qdcount = struct.unpack(">HHH", query[:6])
    if qdcount != 1:
        return struct.pack(">HHHHHH", ident, 0x8000 | 0x0004, 0, 0, 0, 0)  # NOTIMP
    name, end = read_name(query, 12)
    qtype, qclass = struct.unpack(">HH", query[end : end + 4])
    question = query[12 : end + 4]
    ips = records.get(name.lower().rstrip("."))
    rcode, answers = (3, []) if ips is None else (0, [])
    if ips is not None and qtype == 1 and qclass == 1:
        answers = [b"\xc0\x0c" + struct.pack(">HHIH", 1, 1, 5, 4) + socket.inet_aton(ip) for ip in ips]
    out_flags = 0x8000 | 0x0400 | (flags & 0x0100) | 0x0080 | rcode  # response, authoritative, RD echoed, RA
    return struct.pack(">HHHHHH", ident, out_flags, 1, len(answers), 0, 0) + question + b"".join(answers)


def main(argv):
    if len(argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    records = dict(a.split("=", 1) for a in argv[1:])
    records = {k.lower(): v.split(",") for k, v in records.items()}
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind((argv[0], 53))
    print("ready", flush=True)
    while True:
        query, peer = sock.recvfrom(4096)
        try:
            sock.sendto(answer(query, records), peer)
        except (ValueError, IndexError, struct.error):
            continue


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
