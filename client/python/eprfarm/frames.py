"""Frame sequences (client/batch.h): frame lists as `epr submit --frames` takes them, batch ids, and
the per-frame job specs of a batch."""

from __future__ import annotations

import re
import secrets
from typing import Iterable, List, Optional, Tuple, Union

from . import limits as L
from .errors import ArgumentError
from .limits import MAX_NAME_BYTES
from .proto import job_service_pb2 as pb
from .proto import render_settings_pb2 as rs_pb

MAX_FRAME = 9_999_999  # common/camera_animation.h kMaxFrame
MAX_BATCH_FRAMES = 100_000  # client/batch.h kMaxBatchFrames
DEFAULT_WINDOW_RUN = 16  # frames one master renders together (client/batch.h kDefaultWindowRun)


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


def checked_window(frame_window, window_run: Optional[int], spec: pb.JobSpec) -> Tuple[int, int]:
    """The frame window K and the run length N of a batch, ArgumentError unless K and N are in
    common/limits.h's ranges (0 to 16, 1 to 64); a window needs reprojection (mode skip or rp) by the
    deep framebuffer (reproject gl or cpu). N defaults to DEFAULT_WINDOW_RUN; without a window it is 1."""
    k = L.job_whole("frame_window", frame_window, L.FRAME_WINDOW)
    if k == 0:
        if window_run is not None:
            raise ArgumentError("window_run needs a frame_window above 0")
        return 0, 1
    if spec.mode == rs_pb.RENDER_MODE_PT:
        raise ArgumentError("frame_window needs reprojection: mode pt traces every frame alone (use skip or rp)")
    if spec.reprojection.method == rs_pb.REPROJECTION_METHOD_EXACT:
        raise ArgumentError("frame_window needs reproject gl or cpu: exact samples are decided for one camera")
    n = DEFAULT_WINDOW_RUN if window_run is None else window_run
    return k, L.job_whole("window_run", n, L.WINDOW_RUN)


def checked_halving(halving, frame_window: int) -> float:
    """window_halving (frames, 0 to 16; 0: a neighbour's samples count as the frame's own), ArgumentError
    if out of range or given without a frame window."""
    h = L.real("window_halving", halving, 0, L.FRAME_WINDOW.hi, "between 0 and 16 frames")
    if h and not frame_window:
        raise ArgumentError("window_halving needs a frame_window above 0")
    return h


def window_runs(frames: List[int], window_run: int) -> List[Tuple[int, int]]:
    """The runs of a batch's frames (sorted, unique) as `epr submit --frame-window` plans them
    (client/batch.cpp): [first, last] indices into the list, each run at most `window_run` consecutive
    frame numbers (the master renders a run's frames window_first..window_last together and reaches
    the frames at most K numbers away), a skipped number ending a run."""
    runs: List[Tuple[int, int]] = []
    start = 0
    for i in range(1, len(frames) + 1):
        if i == len(frames) or frames[i] != frames[i - 1] + 1 or i - start == window_run:
            runs.append((start, i - 1))
            start = i
    return runs


def run_frames(frames: List[int], window_run: int) -> List[Tuple[int, int]]:
    """For each of `frames` (a batch's list) the first and last frame numbers of its run (window_runs):
    a window job's window_first and window_last."""
    out = []
    for first, last in window_runs(frames, window_run):
        out += [(frames[first], frames[last])] * (last - first + 1)
    return out


def frame_specs(
    spec: pb.JobSpec, batch_id: str, name: str, frames: List[int], frame_window: int = 0, window_run: int = 1
) -> List[pb.JobSpec]:
    """One copy of `spec` per frame, with the batch fields, the job name NAME.0007 and the request id
    BATCH-FRAME (a retried submission does not queue a frame twice), as `epr submit --frames` makes them.
    With a frame window (checked_window) each frame also names its run: frame_window, and window_first
    and window_last, the frame numbers of the run's first and last frame (window_runs); and its seed
    is the batch's plus the frame number, so that the frames of a run trace paths of their own."""
    if len(name.encode()) + 9 > MAX_NAME_BYTES:
        raise ArgumentError(f"batch name is {len(name.encode())} bytes long, at most {MAX_NAME_BYTES - 9}")
    run_of = run_frames(frames, window_run)
    out = []
    for i, frame in enumerate(frames):
        one = pb.JobSpec()
        one.CopyFrom(spec)
        one.name = f"{name}.{frame:04d}"
        one.request_id = f"{batch_id}-{frame}"
        one.batch_id = batch_id
        one.batch_name = name
        one.frame = frame
        one.batch_frames = len(frames)
        if frame_window:
            one.frame_window = frame_window
            one.window_first, one.window_last = run_of[i]
            one.seed = (spec.seed + frame) % (1 << 64)
        out.append(one)
    return out
