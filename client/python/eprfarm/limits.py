"""The ranges of a job's settings and of the client's own arguments, checked before anything is sent.

The job ranges are common/limits.h's, which epr and the master check (tests/client/python compares
the two). A value out of range is an ArgumentError naming the argument, its value and its range, as
epr names its flag ("spp -4 must be between 1 and 1000000"), instead of protobuf's "Value out of
range" or the master's "a size or sample count is absurdly large".
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Optional

from .errors import ArgumentError


@dataclass(frozen=True)
class Range:
    flag: str  # as common/limits.h names it: epr's flag
    lo: float
    hi: float  # inclusive


# common/limits.h
IMAGE_SIDE = Range("--width/--height", 1, 16384)
SPP = Range("--spp", 1, 1000000)
SUBPIXELS = Range("--subpixels", 1, 8)
TILE_SIZE = Range("--tile", 4, 1024)
MAX_DEPTH = Range("--max-depth", 1, 100000)
ROUND_GROWTH = Range("--round-growth", 0, 16)
EPSILON = Range("--epsilon", 0, 1)
FRAME_WINDOW = Range("--frame-window", 0, 16)  # K, frames on each side
WINDOW_RUN = Range("--window-run", 1, 64)  # the frames of one run, window_first..window_last
JOB_RANGES = (IMAGE_SIDE, SPP, SUBPIXELS, TILE_SIZE, MAX_DEPTH, ROUND_GROWTH, EPSILON, FRAME_WINDOW, WINDOW_RUN)
MAX_NAME_BYTES = 256  # kMaxNameBytes: job, batch and worker names, UTF-8

UINT32_MAX = (1 << 32) - 1
UINT64_MAX = (1 << 64) - 1
INT32 = (-(1 << 31), (1 << 31) - 1)
TIMEOUT = (0.001, 86400.0)  # epr's --timeout: seconds, the deadline of one request


def whole(name: str, value, lo: int, hi: int, range_text: Optional[str] = None) -> int:
    """`value` as an int, ArgumentError unless it is a whole number (not a bool) in [lo, hi]."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ArgumentError(f"{name} must be a whole number, not {value!r}")
    value = int(value)
    if not lo <= value <= hi:
        raise ArgumentError(f"{name} {value} must be {range_text or f'between {lo} and {hi}'}")
    return value


def real(
    name: str, value, lo: float = -math.inf, hi: float = math.inf, range_text: Optional[str] = None, above: bool = False
) -> float:
    """`value` as a float, ArgumentError unless it is a finite number in [lo, hi] ((lo, hi] if `above`)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ArgumentError(f"{name} must be a number, not {value!r}")
    value = float(value)
    if not math.isfinite(value) or not lo <= value <= hi or (above and value == lo):
        raise ArgumentError(f"{name} {value:g} must be {range_text or f'between {lo:g} and {hi:g}'}")
    return value


def job_whole(name: str, value, r: Range) -> int:
    return whole(name, value, int(r.lo), int(r.hi))


def job_real(name: str, value, r: Range) -> float:
    return real(name, value, r.lo, r.hi)


def seconds(name: str, value, lo: float = TIMEOUT[0], hi: float = TIMEOUT[1]) -> float:
    """A deadline in seconds: a finite number in [lo, hi]."""
    return real(name, value, lo, hi, f"between {lo:g} and {hi:g} seconds")


def positive_seconds(name: str, value) -> float:
    """A duration in seconds: a finite number above 0."""
    return real(name, value, 0, range_text="a positive number of seconds", above=True)
