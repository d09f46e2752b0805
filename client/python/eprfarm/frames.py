"""Frame sequences (client/batch.h): frame lists as `epr submit --frames` takes them, batch ids, and
the per-frame job specs of a batch."""

from __future__ import annotations

import re
import secrets
from typing import Iterable, List, Optional, Union

from .errors import ArgumentError
from .limits import MAX_NAME_BYTES
from .proto import job_service_pb2 as pb

MAX_FRAME = 9_999_999  # common/camera_animation.h kMaxFrame
MAX_BATCH_FRAMES = 100_000  # client/batch.h kMaxBatchFrames


def parse_frames(frames: Union[str, Iterable[int]]) -> List[int]:
    """Frames as `epr submit --frames` takes them: "1-240", "1-240x2" (every second frame), "1,5,9" or a
    comma-separated mix; or an iterable of frame numbers. Sorted and unique, from 0 to MAX_FRAME."""
    if not isinstance(frames, str):
        out = sorted(set(int(f) for f in frames))
    else:
        out_set = set()
        for part in frames.split(","):
            m = re.fullmatch(r"([0-9]{1,8})(?:-([0-9]{1,8})(?:x([0-9]{1,8}))?)?", part)
            if not m:
                raise ArgumentError(f"frames: '{part}' is not a frame, a range A-B or A-BxSTEP")
            a = int(m.group(1))
            b = int(m.group(2)) if m.group(2) else a
            step = int(m.group(3)) if m.group(3) else 1
            if b < a or step == 0:
                raise ArgumentError(f"frames: range '{part}' is empty")
            if (b - a) // step + 1 + len(out_set) > MAX_BATCH_FRAMES:
                raise ArgumentError(f"frames: more than {MAX_BATCH_FRAMES} frames")
            out_set.update(range(a, b + 1, step))
        out = sorted(out_set)
    if not out:
        raise ArgumentError("frames: a batch needs at least one frame")
    if out[0] < 0 or out[-1] > MAX_FRAME:
        raise ArgumentError(f"frames must lie in 0..{MAX_FRAME}")
    if len(out) > MAX_BATCH_FRAMES:
        raise ArgumentError(f"frames: more than {MAX_BATCH_FRAMES} frames")
    return out


def valid_batch_id(batch_id: str) -> bool:
    """True for an id of 1 to 64 of [A-Za-z0-9_-]."""
    return isinstance(batch_id, str) and re.fullmatch(r"[A-Za-z0-9_-]{1,64}", batch_id) is not None


def checked_batch_id(batch_id: Optional[str]) -> str:
    """`batch_id`, or a fresh one ("b-" and 12 random hex digits); ArgumentError unless 1 to 64 of [A-Za-z0-9_-]."""
    batch_id = batch_id or "b-" + secrets.token_hex(6)
    if not valid_batch_id(batch_id):
        raise ArgumentError(f"batch id '{batch_id}' is not 1 to 64 of [A-Za-z0-9_-]")
    return batch_id


def frame_specs(spec: pb.JobSpec, batch_id: str, name: str, frames: List[int]) -> List[pb.JobSpec]:
    """One copy of `spec` per frame, with the batch fields, the job name NAME.0007 and the request id
    BATCH-FRAME (a retried submission does not queue a frame twice), as `epr submit --frames` makes them."""
    if len(name.encode()) + 9 > MAX_NAME_BYTES:
        raise ArgumentError(f"batch name is {len(name.encode())} bytes long, at most {MAX_NAME_BYTES - 9}")
    out = []
    for frame in frames:
        one = pb.JobSpec()
        one.CopyFrom(spec)
        one.name = f"{name}.{frame:04d}"
        one.request_id = f"{batch_id}-{frame}"
        one.batch_id = batch_id
        one.batch_name = name
        one.frame = frame
        one.batch_frames = len(frames)
        out.append(one)
    return out
