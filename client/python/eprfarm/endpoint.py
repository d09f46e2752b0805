"""One master's connection: its address, gRPC channel and JobService stub."""

from __future__ import annotations

import atexit
import ssl
import threading
import time
import weakref
from typing import List, Optional

import grpc

from .errors import ArgumentError, RpcError
from .proto import job_service_pb2_grpc as pb_grpc


# Channels still open when the interpreter exits are closed first: a channel whose connectivity was
# watched (check_reachable) and left to the finalizers at shutdown can hang the exit.
_open: "weakref.WeakSet[Endpoint]" = weakref.WeakSet()


@atexit.register
def _close_open_endpoints() -> None:
    for endpoint in list(_open):
        endpoint.close()


def pem_roots(ca_file: str) -> bytes:
    """The CA file's bytes; ArgumentError unless it can be read and holds PEM certificates (gRPC
    would only say "empty address list" when connecting)."""
    try:
        with open(ca_file, "rb") as f:
            roots = f.read()
    except OSError as e:
        raise ArgumentError(f"cannot read the CA file '{ca_file}': {e.strerror}") from None
    if not roots.strip():
        raise ArgumentError(f"the CA file '{ca_file}' is empty: it must hold PEM certificates")
    try:
        ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT).load_verify_locations(cadata=roots.decode("latin-1"))
    except (ssl.SSLError, ValueError):
        raise ArgumentError(
            f"the CA file '{ca_file}' is not a PEM file of certificates: it has no readable "
            "'-----BEGIN CERTIFICATE-----' block"
        ) from None
    return roots


class Endpoint:
    """One master: its address, channel and JobService stub."""

    def __init__(
        self, target: str, credentials: Optional[grpc.ChannelCredentials], tls_server_name: str = "", name: str = ""
    ):
        self.target = target
        self.name = name or target  # for messages: the list's entry, or "HOST:PORT (ADDRESS)"
        options = [
            ("grpc.max_receive_message_length", 64 << 20),  # ListJobs pages of large statuses
            ("grpc.primary_user_agent", "eprfarm-python"),
        ]
        if tls_server_name:  # connected by address: the certificate names the host the address came from
            options.append(("grpc.ssl_target_name_override", tls_server_name))
        if credentials is None:
            self.channel = grpc.insecure_channel(target, options=options)
        else:
            self.channel = grpc.secure_channel(target, credentials, options=options)
        self.stub = pb_grpc.JobServiceStub(self.channel)
        self._unsubscribed_at = 0.0  # monotonic time the last connection check ended
        _open.add(self)

    def check_reachable(self, timeout: float) -> None:
        """Raises RpcError unless a connection is established within `timeout` seconds; fails at once
        when the connection is refused (also while the channel still reports a failed attempt: gRPC
        tries again after its reconnection backoff, as the C++ client's channel does)."""
        settled = threading.Event()
        outcome: List[grpc.ChannelConnectivity] = []

        def on_state(state: grpc.ChannelConnectivity) -> None:
            if not settled.is_set() and state in (
                grpc.ChannelConnectivity.READY,
                grpc.ChannelConnectivity.TRANSIENT_FAILURE,
                grpc.ChannelConnectivity.SHUTDOWN,
            ):
                outcome.append(state)
                settled.set()

        self.channel.subscribe(on_state, try_to_connect=True)
        try:
            if not settled.wait(timeout):
                raise RpcError(
                    grpc.StatusCode.DEADLINE_EXCEEDED,
                    "no connection",
                    f"cannot reach master at {self.target} (no connection within {timeout:g} s)",
                    "connect",
                    self.target,
                )
            if outcome[0] != grpc.ChannelConnectivity.READY:
                raise RpcError(
                    grpc.StatusCode.UNAVAILABLE,
                    "connection failed",
                    f"cannot reach master at {self.target} (UNAVAILABLE: connection failed)",
                    "connect",
                    self.target,
                )
        finally:
            self.channel.unsubscribe(on_state)
            self._unsubscribed_at = time.monotonic()

    def close(self) -> None:
        # grpcio's connectivity polling thread notices an unsubscribe within 0.2 s; a channel closed
        # before that makes it print a "Channel closed!" traceback (gRPC issue 18995). Let it stop.
        time.sleep(max(0.0, self._unsubscribed_at + 0.25 - time.monotonic()))
        self.channel.close()
        _open.discard(self)
