"""The exceptions of the eprfarm client.

Every error the package raises is an EprError. The master's refusals (and a master that cannot be
reached) are RpcError, carrying the gRPC status code and the master's reason, with a message that
names the master as `epr` does ("master at localhost:50051 refused SubmitJob: INVALID_ARGUMENT:
--spp 0 must be between 1 and 1000000").
"""

from __future__ import annotations

from typing import Optional

import grpc

# Codes a later call may not meet again: the master away, busy or restarting (wire/rpc/status.h).
TRANSIENT_CODES = frozenset(
    {
        grpc.StatusCode.UNAVAILABLE,
        grpc.StatusCode.DEADLINE_EXCEEDED,
        grpc.StatusCode.RESOURCE_EXHAUSTED,
        grpc.StatusCode.ABORTED,
        grpc.StatusCode.CANCELLED,
        grpc.StatusCode.UNKNOWN,
        grpc.StatusCode.INTERNAL,
    }
)


class EprError(Exception):
    """Base class of every error raised by the eprfarm client."""


class RpcError(EprError):
    """An error status from the master, or no answer from it.

    Attributes:
        code: the grpc.StatusCode (e.g. grpc.StatusCode.INVALID_ARGUMENT).
        reason: the master's reason (the status details), "" if it gave none.
        call: the RPC that failed ("SubmitJob", "FetchResult(EXR)", "connect", ...).
        target: the master's address.
    """

    def __init__(self, code: grpc.StatusCode, reason: str, message: str, call: str = "", target: str = ""):
        super().__init__(message)
        self.code = code
        self.reason = reason
        self.call = call
        self.target = target

    @property
    def code_name(self) -> str:
        """The status code's name, e.g. "UNAUTHENTICATED"."""
        return self.code.name

    @property
    def unreachable(self) -> bool:
        """True when the master could not be reached or did not answer in time (UNAVAILABLE,
        DEADLINE_EXCEEDED), as opposed to an answer that refused the request."""
        return self.code in (grpc.StatusCode.UNAVAILABLE, grpc.StatusCode.DEADLINE_EXCEEDED)


class ArgumentError(EprError, ValueError):
    """An argument of the wrong type or out of its range, found before anything is sent; the message
    names the argument and its range ("spp -4 must be between 1 and 1000000")."""


class SceneError(EprError, ValueError):
    """A scene that cannot be bundled: a file missing, unreadable or outside the scene's folder.
    The message names the file (and line) as `epr submit` does."""


class TokenError(EprError, ValueError):
    """A token file or $EPR_TOKEN that cannot be used; the message names the file and the reason."""


class JobError(EprError):
    """A job whose results cannot be had: it FAILED (reason: its error message) or has not ended
    (fetch its latest committed round with partial=True)."""

    def __init__(self, message: str, job_id: str, state: str, reason: Optional[str] = None):
        super().__init__(message)
        self.job_id = job_id
        self.state = state
        self.reason = reason or ""
