"""What the master reports about jobs (epr.v1.JobStatus) and what a job's results are
(common/result_kinds.h), as Python values."""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from typing import TYPE_CHECKING, Optional, Tuple, Union

from .errors import ArgumentError
from .proto import job_service_pb2 as pb
from .proto import render_settings_pb2 as rs_pb

if TYPE_CHECKING:
    import numpy

# Render modes and job states by their names in `epr`.
MODES = {"pt": rs_pb.RENDER_MODE_PT, "rp": rs_pb.RENDER_MODE_RP, "skip": rs_pb.RENDER_MODE_SKIP}
STATES = {
    pb.JOB_STATE_QUEUED: "QUEUED",
    pb.JOB_STATE_RUNNING: "RUNNING",
    pb.JOB_STATE_DONE: "DONE",
    pb.JOB_STATE_FAILED: "FAILED",
    pb.JOB_STATE_CANCELLED: "CANCELLED",
}
TERMINAL_STATES = frozenset({pb.JOB_STATE_DONE, pb.JOB_STATE_FAILED, pb.JOB_STATE_CANCELLED})


@dataclass(frozen=True)
class JobStatus:
    """A job's status as the master reports it (epr.v1.JobStatus); `proto` holds every field."""

    id: str
    name: str
    state: str  # "QUEUED", "RUNNING", "DONE", "FAILED" or "CANCELLED"
    error_message: str  # FAILED only: why
    mode: str  # "skip", "rp" or "pt"
    width: int
    height: int
    target_spp: int  # P
    round: int  # rounds committed so far
    rounds_planned: int
    spp_min: int  # effective samples per pixel M + M', the slowest pixel
    spp_mean: float  # ... and averaged over the image
    reprojected_per_pixel_mean: float  # M' alone
    pixels_skipped: int  # in the current (or last) round
    paths_traced: int
    paths_skipped: int
    seconds_elapsed: float
    eta_seconds: Optional[float]  # None while unknown
    budget_exhausted: bool
    proto: pb.JobStatus
    master: str = ""  # in a listing of several masters (Client.list): the address it was listed at

    @classmethod
    def from_proto(cls, s: pb.JobStatus) -> "JobStatus":
        mode = {v: k for k, v in MODES.items()}.get(s.effective.mode, "")
        return cls(
            id=s.id,
            name=s.name,
            state=STATES.get(s.state, "UNSPECIFIED"),
            error_message=s.error_message,
            mode=mode,
            width=s.effective.width,
            height=s.effective.height,
            target_spp=s.target_spp,
            round=s.round,
            rounds_planned=s.rounds_planned,
            spp_min=s.spp_min,
            spp_mean=s.spp_mean,
            reprojected_per_pixel_mean=s.reprojected_per_pixel_mean,
            pixels_skipped=s.pixels_skipped,
            paths_traced=s.paths_traced,
            paths_skipped=s.paths_skipped,
            seconds_elapsed=s.seconds_elapsed,
            eta_seconds=s.eta_seconds if s.eta_seconds >= 0 else None,
            budget_exhausted=s.budget_exhausted,
            proto=s,
        )

    @property
    def batch_id(self) -> str:
        """The batch (submit_frames, `epr submit --frames`) the job belongs to; "" for none."""
        return self.proto.batch_id

    @property
    def frame(self) -> Optional[int]:
        """The frame number a batch's job renders; None outside a batch."""
        return self.proto.frame if self.proto.HasField("frame") else None

    @property
    def terminal(self) -> bool:
        """DONE, FAILED or CANCELLED: the job will not change any more."""
        return self.proto.state in TERMINAL_STATES

    @property
    def percent(self) -> float:
        """Completion in [0, 100], as `epr watch`'s bar: SKIP ends when every pixel has M + M' >= P, so
        its slowest pixel measures it; PT and RP run exactly rounds_planned rounds."""
        target = max(1, self.target_spp)
        if self.proto.state == pb.JOB_STATE_DONE:
            frac = 1.0
        elif self.mode == "skip":
            frac = self.spp_min / target
        elif self.rounds_planned:
            frac = self.round / self.rounds_planned
        else:
            frac = self.spp_mean / target
        return 100.0 * min(1.0, max(0.0, frac))


@dataclass(frozen=True)
class ResultKind:
    """One result file of a job (common/result_kinds.h)."""

    name: str  # as `epr` names it: "exr", "png", "json", "pathtrace.exr", ...
    suffix: str  # appended to the output prefix
    array: str  # key in get(as_arrays=True) for EXR kinds, "" otherwise
    proto: int  # epr.v1.ResultKind


# In the order `epr get` fetches them.
RESULT_KINDS: Tuple[ResultKind, ...] = (
    ResultKind("exr", ".exr", "combined", pb.RESULT_KIND_EXR),
    ResultKind("png", ".png", "", pb.RESULT_KIND_PNG),
    ResultKind("json", ".json", "", pb.RESULT_KIND_JSON),
    ResultKind("pathtrace.exr", ".pathtrace.exr", "pathtrace", pb.RESULT_KIND_PATH_TRACED_EXR),
    ResultKind("counts.exr", ".counts.exr", "counts", pb.RESULT_KIND_COUNTS_EXR),
    ResultKind("reprojection.exr", ".reprojection.exr", "reprojection", pb.RESULT_KIND_REPROJECTED_EXR),
    ResultKind("samples.exr", ".samples.exr", "samples", pb.RESULT_KIND_SAMPLES_EXR),
    ResultKind("samples.png", ".samples.png", "", pb.RESULT_KIND_STATS_IMAGE),
)
_KIND_BY_NAME = {k.name: k for k in RESULT_KINDS}


def result_kind(kind: Union[str, ResultKind]) -> ResultKind:
    if isinstance(kind, ResultKind):
        return kind
    try:
        return _KIND_BY_NAME[kind]
    except KeyError:
        raise ArgumentError(f"unknown result kind '{kind}'; one of {', '.join(_KIND_BY_NAME)}") from None


@dataclass(frozen=True)
class FetchedFile:
    """One result file written by get() or fetch()."""

    kind: str  # ResultKind.name
    path: str
    bytes: int
    round: int  # the committed round the file reflects
    partial: bool  # the job had not ended


@dataclass(frozen=True)
class ResultBytes:
    """One result held in memory (fetch_bytes)."""

    kind: str
    data: bytes
    media_type: str
    round: int
    partial: bool


def output_prefix_error(prefix: str) -> Optional[str]:
    """Why `prefix` cannot be an output prefix (PREFIX.exr, PREFIX.png, ... are written), or None."""
    if not prefix:
        return "the output prefix is empty (files would be named .exr, .png, ...)"
    last = os.path.basename(prefix)
    if last in ("", ".", ".."):
        folder = prefix[:-1] if prefix.endswith("/") else prefix
        return f"'{prefix}' names a folder, not a file prefix; give one such as '{folder}/render'"
    if os.path.isdir(prefix):
        return f"'{prefix}' is a folder; give a file prefix inside it such as '{prefix}/render'"
    return None



def decode_exr(data: bytes) -> numpy.ndarray:
    """An EXR file's pixels as a float32 array (height, width, channels), through OpenImageIO."""
    import OpenImageIO as oiio

    with tempfile.NamedTemporaryFile(suffix=".exr") as f:
        f.write(data)
        f.flush()
        inp = oiio.ImageInput.open(f.name)
        if inp is None:
            raise ValueError(f"cannot decode the EXR result: {oiio.geterror()}")
        try:
            pixels = inp.read_image(format="float")
            if pixels is None:
                raise ValueError(f"cannot decode the EXR result: {inp.geterror()}")
            spec = inp.spec()
            return pixels.reshape(spec.height, spec.width, spec.nchannels)
        finally:
            inp.close()
