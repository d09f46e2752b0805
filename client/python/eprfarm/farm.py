"""Client: the eprfarm client across one or several masters, as `epr --master A,B` (client/farm.h).

    c = eprfarm.Client("m1:50051,m2:50051")      # or ["m1:50051", "m2:50051"], or $EPR_MASTER
    job = c.submit("builtin:cornell")            # queued on the master with the least work
    c.get(job, out="cornell")                    # found on the master whose name the id carries

Masters share nothing; a job id names its master (NAME.j000123-abcd, MasterInfo.name). A call on one
job asks every master its name (GetMasterInfo, all at once) and goes to the one whose name the id
carries; an id without a name, or a name no master answers to, is looked for with GetJob on every
master. A submission goes to the master with the fewest samples left to trace (then the fewest
jobs, then list order). list() merges every master's jobs; a master that does not answer is logged
and named in the result's `failed`. With a single master nothing is asked beforehand: every call
goes to it, as MasterClient's do. Nothing is cached between calls but where this client uploaded
scenes.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Dict, Iterable, Iterator, List, Optional, Sequence, Set, Tuple, TypeVar, Union

import grpc

from . import frames as _frames
from . import scene as _scene
from .client import MasterClient, _default_job_name
from .endpoint import Endpoint
from .errors import ArgumentError, EprError, RpcError
from .proto import job_service_pb2 as pb
from .proto import scene_pb2 as scene_pb
from .status import JobStatus

log = logging.getLogger("eprfarm")
T = TypeVar("T")


def job_id_master(job_id: str) -> str:
    """The master-name part of a job id ("alpha" of "alpha.j000001-beef"); "" when it has none."""
    return job_id.split(".", 1)[0] if "." in job_id else ""


class JobList(list):
    """list()'s jobs (JobStatus, newest first), with `failed`: the masters that could not be listed,
    by label ("NAME (ADDRESS)" or the address), each with its RpcError. Their jobs are missing."""

    def __init__(self, jobs: Iterable[JobStatus] = (), failed: Optional[Dict[str, RpcError]] = None):
        super().__init__(jobs)
        self.failed: Dict[str, RpcError] = failed or {}


class _OneMaster(MasterClient):
    """A Client's view of one of its masters: the same options, token and channels, calls to it alone."""

    def upload_scene(self, bundle: _scene.SceneBundle) -> str:
        content_hash = super().upload_scene(bundle)
        with self._lock:
            self._scene_masters.setdefault(content_hash, set()).add(self.target)
        return content_hash

    def master_info(self) -> pb.MasterInfo:
        """The master's name and load (GetMasterInfo)."""
        try:
            return self._endpoint().stub.GetMasterInfo(
                pb.MasterInfoRequest(), timeout=self.timeout, metadata=self._metadata()
            )
        except grpc.RpcError as e:
            raise self._error(e, "GetMasterInfo") from None


@dataclasses.dataclass
class _Probe:
    master: _OneMaster
    info: Optional[pb.MasterInfo]
    error: Optional[RpcError]

    @property
    def label(self) -> str:
        name = self.master._endpoint().name
        return f"{self.info.name} ({name})" if self.info and self.info.name else name


class Client(MasterClient):
    """A connection to one or several eprfarm masters (see the module's doc and MasterClient for the
    arguments: `master` may be "A:50051,B:50051" or a list; the token and TLS options apply to every
    master). With several masters, submit, job_spec, upload_scene and submit_spec go to the least
    loaded master, status, watch, wait, cancel, fetch, fetch_bytes and get to the master holding the
    job, list merges every master's jobs, submit_frames spreads the frames over the masters and
    cancel_batch cancels a batch's jobs on every master."""

    def __init__(self, master: Union[str, Sequence[str], None] = None, **options):
        super().__init__(master, **options)
        self._scene_masters: Dict[str, Set[str]] = {}  # content hash -> targets this client uploaded it to

    @property
    def several(self) -> bool:
        return len(self._endpoints) > 1

    @property
    def targets(self) -> List[str]:
        """Every master's address (`target` is the first's)."""
        return [e.target for e in self._endpoints]

    def _on(self, endpoint: Endpoint) -> _OneMaster:
        view = _OneMaster.__new__(_OneMaster)
        view.__dict__.update(self.__dict__)
        view._endpoints = [endpoint]
        return view

    def masters(self) -> List[MasterClient]:
        """One client per master, in list order, sharing this client's options and connections."""
        return [self._on(e) for e in self._endpoints]

    def _for_each(self, fn: Callable[[_OneMaster], T], masters: Sequence[_OneMaster]):
        """[(fn(master), None) or (None, RpcError)] for every master, all at once."""

        def attempt(m: _OneMaster):
            try:
                return fn(m), None
            except RpcError as e:
                return None, e

        if len(masters) <= 1:
            return [attempt(m) for m in masters]
        with ThreadPoolExecutor(len(masters)) as pool:
            return list(pool.map(attempt, masters))

    def _probe(self, masters: Optional[Sequence[_OneMaster]] = None) -> List[_Probe]:
        masters = self.masters() if masters is None else masters
        return [_Probe(m, i, e) for m, (i, e) in zip(masters, self._for_each(lambda m: m.master_info(), masters))]

    def least_loaded(self, among: Optional[Set[str]] = None) -> MasterClient:
        """The master a new job goes to: the single one (unasked), else the master with the fewest
        samples left (then the fewest jobs, then list order), only of the targets `among` if any of
        them answered. Masters that do not answer are skipped (logged); RpcError when none answered."""
        if not self.several:
            return self._on(self._endpoints[0])
        probes = self._probe()
        for p in probes:
            if p.error:
                log.warning("master %s did not answer (%s); skipped", p.label, p.error)
        live = [p for p in probes if p.info is not None]
        if among and any(p.master.target in among for p in live):
            live = [p for p in live if p.master.target in among]
        if not live:
            raise probes[0].error
        return min(live, key=lambda p: (p.info.samples_left, p.info.jobs_queued + p.info.jobs_running)).master

    def locate(self, job_id: str) -> MasterClient:
        """The master holding `job_id` (the single one, unasked). RpcError NOT_FOUND when every master
        answered and none has it; the down masters' error when the job may be on one of them."""
        if not self.several:
            return self._on(self._endpoints[0])
        probes = self._probe()
        name = job_id_master(job_id)
        for p in probes:
            if name and p.info and p.info.name == name:
                return p.master
        # No master answers to the id's name (it has none, or its master is down or renamed): ask them all.
        asked = [p for p in probes if not p.error]
        for p, (found, error) in zip(asked, self._for_each(lambda m: m.status(job_id), [p.master for p in asked])):
            if found:
                return p.master
            if error.code != grpc.StatusCode.NOT_FOUND:
                p.error = error
        answered = ", ".join(p.label for p in probes if not p.error)
        away = [p for p in probes if p.error]
        if not away:
            message = f"no master knows job {job_id} (asked {answered})"
            raise RpcError(grpc.StatusCode.NOT_FOUND, "unknown job", message, "GetJob", ",".join(self.targets))
        first = away[0].error
        message = (
            f"job {job_id} is not on {answered or 'any master'}; it may be on "
            f"{', '.join(p.label for p in away)}, which did not answer ({first})"
        )
        raise RpcError(first.code, first.reason, message, first.call, first.target)

    # ---- submitting: the least loaded master ----------------------------------------------------

    def job_spec(self, scene: str, **options) -> pb.JobSpec:
        if not self.several:
            return super().job_spec(scene, **options)
        return self.least_loaded().job_spec(scene, **options)  # a large scene is uploaded there

    def upload_scene(self, bundle: _scene.SceneBundle) -> str:
        if not self.several:
            return super().upload_scene(bundle)
        return self.least_loaded().upload_scene(bundle)

    def submit(self, scene: str, **options) -> str:
        if not self.several:
            return super().submit(scene, **options)
        return self.least_loaded().submit(scene, **options)

    def submit_spec(self, spec: pb.JobSpec) -> str:
        """Queues a ready JobSpec; with several masters on the least loaded one, of those this client
        uploaded the spec's scene to when it names an uploaded scene."""
        if not self.several:
            return super().submit_spec(spec)
        among = None
        if spec.scene.WhichOneof("source") == "uploaded_hash":
            with self._lock:
                among = set(self._scene_masters.get(spec.scene.uploaded_hash, ()))
        return self.least_loaded(among).submit_spec(spec)

    def submit_frames(
        self,
        scene: str,
        frames: Union[str, Iterable[int]],
        batch_id: Optional[str] = None,
        frame_window: int = 0,
        window_run: Optional[int] = None,
        window_halving: float = 0.0,
        **options,
    ) -> Tuple[str, List[str]]:
        """Queues a batch of frames of the scene's camera animation as `epr submit --frames` does: one
        job per frame (without a camera: the master takes the scene's camera at the frame), the scene
        uploaded once to each master that gets frames. `frames` as frames.parse_frames takes them;
        `name` (default: the scene's) names the batch; the other options as submit's, without a
        camera. With several masters the frames are spread one by one, each to the master with the
        least work (samples left at the start, plus the frames given to it). The batch id and the job
        ids, in frame order.

        `frame_window` K (0 to 16; 0, the default: every frame alone) renders the frames in runs of
        at most `window_run` (1 to 64, default 16) consecutive frame numbers (frames.window_runs, as
        `epr submit --frame-window K --window-run N` plans them), each run on one master with its
        rounds in step, a vertex traced for one frame also reprojected into the run's frames at most
        K frame numbers away; each frame's seed is then `seed` plus its number. `window_halving` H
        (0 to 16 frames; 0, the default: all alike) weighs a vertex traced d frames away at 2^(-d/H)
        of the frame's own in M' and the image (`epr submit --window-halving`). With several masters
        whole runs are spread, each to the master with the least work. A window needs mode skip or
        rp and reproject gl or cpu.

        Every argument is checked before anything is sent, and every frame before any is queued: each
        master that gets frames uploads the scene and checks the scene's camera animation at all of
        its frames (CheckFrames). Should a master still refuse a frame when it is submitted, the frames
        queued before it are cancelled: the error (its `batch_id` set) names the batch, the frame and
        them."""
        if any(options.get(k) is not None for k in ("eye", "look", "up", "fov")):
            raise ArgumentError("the frames' cameras come from the scene's animation: give no eye, look, up or fov")
        frame_list = _frames.parse_frames(frames)
        batch_id = _frames.checked_batch_id(batch_id)
        name = options.pop("name", None) or os.path.splitext(_default_job_name(scene))[0]
        options.pop("request_id", None)
        planner = self._on(self._endpoints[0])
        planner.inline_scene_limit = float("inf")  # nothing uploaded while planning
        template = planner.job_spec(scene, name=name, **options)
        bundle = _scene.bundle_scene(scene) if template.scene.WhichOneof("source") == "files" else None
        scene_ref = scene_pb.SceneBundle()
        scene_ref.CopyFrom(template.scene)
        template.ClearField("scene")
        frame_window, window_run = _frames.checked_window(frame_window, window_run, template)
        specs = _frames.frame_specs(template, batch_id, name, frame_list, frame_window, window_run)
        for spec in specs:
            spec.window_halving = _frames.checked_halving(window_halving, frame_window)
        where, masters = self._spread(specs, _frames.window_runs(frame_list, window_run))
        ids: List[str] = [""] * len(specs)
        placed = []
        queued: List[Tuple[_OneMaster, int]] = []  # (master, index) of every frame queued so far
        frame: Optional[int] = None  # the frame being queued; None while uploading the scene
        mine = [[i for i, m in enumerate(where) if m == index] for index in range(len(masters))]
        refs: List[Optional[scene_pb.SceneBundle]] = [None] * len(masters)
        try:
            for index, master in enumerate(masters):  # every frame checked before any is queued
                if not mine[index]:
                    continue
                frame = None
                refs[index] = scene_ref
                if bundle is not None:  # one upload for every frame
                    refs[index] = scene_pb.SceneBundle(uploaded_hash=master.upload_scene(bundle))
                check = pb.JobSpec()
                check.CopyFrom(specs[mine[index][0]])
                for field in ("frame", "frame_window", "window_first", "window_last", "window_halving"):  # the frames' cameras alone
                    check.ClearField(field)
                check.scene.CopyFrom(refs[index])
                try:
                    master.check_frames(check, [frame_list[i] for i in mine[index]])
                except RpcError as e:
                    raise self._refused_frames(batch_id, e) from None
            for index, master in enumerate(masters):
                for i in mine[index]:
                    frame = frame_list[i]
                    specs[i].scene.CopyFrom(refs[index])
                    ids[i] = master.submit_spec(specs[i])
                    queued.append((master, i))
                if mine[index]:
                    placed.append(f"{len(mine[index])} at {master._endpoint().name}")
        except EprError as e:
            if getattr(e, "batch_id", None):
                raise

            raise self._withdraw(batch_id, frame, e, [(m, frame_list[i], ids[i]) for m, i in queued]) from None
        log.info("batch %s (%s): %d frame(s) queued: %s", batch_id, name, len(ids), ", ".join(placed))
        return batch_id, ids

    @staticmethod
    def _refused_frames(batch_id: str, error: RpcError) -> RpcError:
        """A batch refused by a master's check of its frames: nothing was queued."""
        out = RpcError(error.code, error.reason, f"batch {batch_id}: {error}; no frame was queued", error.call,
                       error.target)
        out.batch_id = batch_id
        return out

    @staticmethod
    def _withdraw(batch_id: str, frame: Optional[int], error: EprError, queued) -> EprError:
        """A batch whose frame (or scene upload) was refused: cancels the frames queued before it
        (the master checks each frame's camera when it is submitted, so a bad frame is found only
        then) and returns the error to raise, naming the batch and what became of its frames."""
        where = f"frame {frame}" if frame is not None else "the scene's upload"
        left = []
        for master, f, job in queued:
            try:
                master.cancel(job)
            except RpcError as e:
                left.append(f"frame {f} ({job}: {e})")
        if not queued:
            outcome = "no frame was queued"
        elif not left:
            outcome = f"the {len(queued)} frame(s) queued before it were cancelled"
        else:
            outcome = (
                f"of the {len(queued)} frame(s) queued before it, these could not be cancelled: {'; '.join(left)} "
                f"(cancel_batch('{batch_id}') cancels them)"
            )
        message = f"batch {batch_id}: {where}: {error}; {outcome}"
        if isinstance(error, RpcError):
            out: EprError = RpcError(error.code, error.reason, message, error.call, error.target)
        else:
            out = EprError(message)
        out.batch_id = batch_id
        return out

    def _spread(
        self, specs: List[pb.JobSpec], runs: List[Tuple[int, int]]
    ) -> Tuple[List[int], List[_OneMaster]]:
        """For each spec the index of the master it goes to, and the masters: each run of specs
        ([first, last] indices; one spec a run without a frame window) to one master."""
        masters = self.masters()
        if not self.several:
            return [0] * len(specs), masters
        probes = self._probe(masters)
        for p in probes:
            if p.error:
                log.warning("master %s did not answer (%s); no frame goes to it", p.label, p.error)
        load = [float(p.info.samples_left) if p.info else None for p in probes]
        if all(x is None for x in load):
            raise probes[0].error
        where = []
        for first, last in runs:
            best = min((i for i, x in enumerate(load) if x is not None), key=lambda i: load[i])
            for spec in specs[first : last + 1]:
                where.append(best)
                load[best] += float(spec.width) * spec.height * spec.target_spp
        return where, masters

    # ---- one job: the master holding it ---------------------------------------------------------

    def status(self, job_id: str) -> JobStatus:
        return super().status(job_id) if not self.several else self.locate(job_id).status(job_id)

    def cancel(self, job_id: str) -> JobStatus:
        return super().cancel(job_id) if not self.several else self.locate(job_id).cancel(job_id)

    def watch(self, job_id: str, min_interval_ms: int = 0) -> Iterator[JobStatus]:
        master = self.locate(job_id) if self.several else super()
        yield from master.watch(job_id, min_interval_ms)

    def fetch_bytes(self, job_id: str, kind="exr", partial: bool = False):
        master = self.locate(job_id) if self.several else super()
        return master.fetch_bytes(job_id, kind, partial)

    def fetch(self, job_id: str, kind, path: str, partial: bool = False):
        master = self.locate(job_id) if self.several else super()
        return master.fetch(job_id, kind, path, partial)

    def get(self, job_id: str, out: Optional[str] = None, *, partial: bool = False, as_arrays: bool = False):
        master = self.locate(job_id) if self.several else super()
        return master.get(job_id, out, partial=partial, as_arrays=as_arrays)

    def check_reachable(self) -> None:
        """Raises the first master's RpcError unless every master is reached within `timeout`."""
        for _, error in self._for_each(lambda m: m.check_reachable(), self.masters()):
            if error:
                raise error

    # ---- every master ---------------------------------------------------------------------------

    def cancel_batch(self, batch_id: str) -> JobList:
        """Cancels every job of the batch `batch_id` (submit_frames, `epr submit --frames`, the Blender
        add-on's Render Frames on Farm) on every master holding some; returns the batch's jobs after
        the call (as list(batch=...): newest first; those that had ended unchanged). RpcError NOT_FOUND
        when no master has a job of the batch; RpcError when a master could not be listed or a cancel
        failed, after the other jobs were cancelled (the message names what may still run)."""
        if not _frames.valid_batch_id(batch_id):
            raise ArgumentError(f"batch id {batch_id!r} is not 1 to 64 of [A-Za-z0-9_-]")
        jobs = self.list(batch=batch_id)
        views = {m.target: m for m in self.masters()}
        first = views[self.target]

        def cancel_each(master: _OneMaster) -> List[Tuple[int, JobStatus, Optional[RpcError]]]:
            out = []
            for n, s in enumerate(jobs):
                if (s.master or first.target) != master.target or s.terminal:
                    continue
                try:
                    out.append((n, dataclasses.replace(master.cancel(s.id), master=s.master), None))
                except RpcError as e:
                    out.append((n, s, e))
            return out

        results = [r for found, _ in self._for_each(cancel_each, list(views.values())) for r in found or ()]
        problems = [f"{label} could not be listed ({e})" for label, e in jobs.failed.items()]
        for n, s, error in results:
            jobs[n] = s
            if error:
                problems.append(f"job {s.id} (frame {s.frame}) was not cancelled ({error})")
        if problems:
            errors = [e for _, _, e in results if e] + list(jobs.failed.values())
            cancelled = sum(1 for _, _, e in results if not e)
            message = f"batch {batch_id}: {cancelled} job(s) cancelled, but " + "; ".join(problems)
            raise RpcError(errors[0].code, errors[0].reason, message, "CancelJob", errors[0].target)
        if not jobs:
            asked = ", ".join(m._endpoint().name for m in views.values())
            raise RpcError(grpc.StatusCode.NOT_FOUND, "unknown batch", f"no master has a job of batch {batch_id} "
                           f"(asked {asked})", "ListJobs", ",".join(self.targets))  # fmt: skip
        return jobs

    def list(
        self, states: Optional[Iterable[str]] = None, limit: int = 0, batch: Optional[str] = None
    ) -> JobList:
        """Jobs newest first (by submission time), optionally only those in `states` and of the batch
        `batch`, at most `limit` (0: all). With several masters: every master's jobs, each JobStatus
        with `master` (the address it was listed at); the masters that could not be listed are logged
        and in the result's `failed`. RpcError when no master could be listed."""
        if not self.several:
            return JobList(super().list(states, limit, batch))
        states = list(states or ())
        masters = self.masters()
        results = self._for_each(lambda m: m.list(states, limit, batch), masters)
        jobs: List[JobStatus] = []
        failed: Dict[str, RpcError] = {}
        for m, (found, error) in zip(masters, results):
            if error:
                label = m._endpoint().name
                failed[label] = error
                what = "did not answer" if error.unreachable else "refused"
                log.warning("master %s %s (%s); its jobs are missing", label, what, error)
                continue
            jobs.extend(dataclasses.replace(s, master=m.target) for s in found)
        if len(failed) == len(masters):
            raise results[0][1]
        jobs.sort(key=lambda s: s.proto.submitted_unix_ms, reverse=True)  # stable: list order on ties
        return JobList(jobs[:limit] if limit else jobs, failed)
