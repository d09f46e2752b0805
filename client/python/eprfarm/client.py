"""Client: the client side of epr.v1.JobService (proto/epr/v1/job_service.proto) in Python.

It mirrors the C++ JobClient behind `epr submit`, `watch`, `get`, `list` and `cancel`
(client/job_client.h): the same job defaults and scene bundling, the same token and TLS options, the
same deadlines (each call has one, so nothing hangs on a master that is down or silent), the same
result files.

    import eprfarm
    c = eprfarm.Client("localhost:50051")            # token: token=, token_file= or $EPR_TOKEN
    job = c.submit("builtin:cornell", width=256, height=256, spp=64)
    for status in c.watch(job):
        print(f"{status.percent:5.1f}%  round {status.round}  spp {status.spp_mean:.1f}")
    files = c.get(job, out="out/cornell")             # out/cornell.exr, .png, .json, ...
    images = c.get(job, as_arrays=True)               # {"combined": float32 array (H, W, 3), ...}
"""

from __future__ import annotations

import hashlib
import logging
import os
import secrets
import threading
import time
from typing import TYPE_CHECKING, Callable, Dict, Iterable, Iterator, List, Optional, Sequence, Tuple, Union

import grpc

from . import job_settings as S
from . import limits as L
from . import scene as _scene
from .auth import configured_token, is_valid_token
from .endpoint import Endpoint, pem_roots
from .errors import TRANSIENT_CODES, ArgumentError, JobError, RpcError
from .masters import master_endpoints
from .proto import job_service_pb2 as pb
from .proto import render_settings_pb2 as rs_pb
from .proto import scene_pb2 as scene_pb
from .status import MODES, RESULT_KINDS, STATES, TERMINAL_STATES, FetchedFile, JobStatus, ResultBytes, ResultKind
from .status import decode_exr, output_prefix_error, result_kind

if TYPE_CHECKING:
    import numpy

log = logging.getLogger("eprfarm")

DEFAULT_MASTER = "localhost:50051"
CHUNK_BYTES = 1 << 20  # SceneFileData.data and ResultData.data carry at most 1 MiB


def _default_job_name(scene: str) -> str:
    name = scene[len(_scene.BUILTIN_PREFIX) :] if scene.startswith(_scene.BUILTIN_PREFIX) else os.path.basename(scene)
    return name.encode()[:L.MAX_NAME_BYTES].decode("utf-8", "ignore")


def _describe(code: grpc.StatusCode, details: str) -> str:
    return f"{code.name}: {details}" if details else code.name


class MasterClient:
    """A connection to an eprfarm master's JobService: every call goes to _endpoint(), the first
    master of the list. eprfarm.Client (farm.py) routes each call to one of several masters.

    Args:
        master: "HOST:PORT", a comma-separated list of masters or a list of them (masters.py); default
            $EPR_MASTER, else localhost:50051 (as `epr`).
        token: the bearer token itself; or
        token_file: a file holding it; with neither, $EPR_TOKEN if set (wire/rpc/token.h's rule).
        tls: connect over TLS (the system's CA roots unless ca_file).
        ca_file: PEM file of CA roots for TLS (implies tls).
        timeout: deadline of unary calls and of connection checks, seconds: 0.001 to 86400 (epr's
            --timeout, 10).
        transfer_timeout: deadline of one result download, seconds.
        watch_call_timeout: one WatchJob call runs this long before it is re-issued, seconds.
        watch_reconnect_timeout: a watch whose master went away retries this long, seconds.
        upload_progress: called as upload_progress(sent_bytes, total_bytes) while a large scene uploads.

    No connection is made until the first call. Not tied to one thread: calls may run in several.
    """

    # How a refusal for want of the right token says what to do (an application names its own fields).
    token_hint = "give the master's token with token= or token_file=, or $EPR_TOKEN"
    # File scenes up to this size travel inline in the JobSpec (the master's message limit is 4 MiB
    # for the whole spec); larger ones are streamed with UploadScene first.
    inline_scene_limit = 3 << 20
    min_transfer_bytes_per_second = 256 * 1024  # slowest upload accepted
    min_scene_load_bytes_per_second = 1e6  # slowest scene parse on the master accepted

    def __init__(
        self,
        master: Union[str, Sequence[str], None] = None,
        *,
        token: Optional[str] = None,
        token_file: Optional[str] = None,
        tls: bool = False,
        ca_file: Optional[str] = None,
        timeout: float = 10.0,
        transfer_timeout: float = 600.0,
        watch_call_timeout: float = 300.0,
        watch_reconnect_timeout: float = 60.0,
        upload_progress: Optional[Callable[[int, int], None]] = None,
    ):
        if master is None:
            master = os.environ.get("EPR_MASTER") or DEFAULT_MASTER
        endpoints = master_endpoints(master)  # ArgumentError when malformed
        if token is not None and token_file is not None:
            raise ArgumentError("give token or token_file, not both")
        if token is not None:
            if not is_valid_token(token):
                raise ArgumentError("the bearer token must be printable ASCII without spaces")
            self._token: Optional[str] = token
        else:
            self._token = configured_token(token_file)
        self.timeout = L.seconds("timeout", timeout)
        self.transfer_timeout = L.positive_seconds("transfer_timeout", transfer_timeout)
        self.watch_call_timeout = L.positive_seconds("watch_call_timeout", watch_call_timeout)
        self.watch_reconnect_timeout = L.positive_seconds("watch_reconnect_timeout", watch_reconnect_timeout)
        credentials = None
        if tls or ca_file:
            roots = pem_roots(ca_file) if ca_file else None
            credentials = grpc.ssl_channel_credentials(root_certificates=roots)
        self.upload_progress = upload_progress
        # The masters this client talks to. Every call goes through _endpoint().
        self._endpoints = [Endpoint(e.target, credentials, e.tls_server_name, e.name) for e in endpoints]
        self._uploaded_bytes: Dict[str, int] = {}  # scenes this client uploaded, by hash
        self._lock = threading.Lock()

    # ---- plumbing -------------------------------------------------------------------------------

    @property
    def target(self) -> str:
        """The master's address."""
        return self._endpoint().target

    def _endpoint(self) -> Endpoint:
        return self._endpoints[0]

    def _metadata(self) -> Optional[List[Tuple[str, str]]]:
        return [("authorization", f"Bearer {self._token}")] if self._token else None

    def _error(self, e: grpc.RpcError, call: str) -> RpcError:
        """The RpcError for a failed call, with a message naming the master as `epr` does."""
        code = e.code() if e.code() is not None else grpc.StatusCode.UNKNOWN
        details = e.details() or ""
        return self._status_error(code, details, call)

    def _status_error(self, code: grpc.StatusCode, details: str, call: str) -> RpcError:
        target = self.target
        detail = _describe(code, details)
        if code == grpc.StatusCode.UNAVAILABLE:
            message = f"cannot reach master at {target} ({detail})"
        elif code == grpc.StatusCode.DEADLINE_EXCEEDED:
            message = f"master at {target} did not answer {call} in time ({detail})"
        elif code == grpc.StatusCode.CANCELLED:
            message = f"{call} to master at {target} was cancelled"
        else:
            message = f"master at {target} refused {call}: {detail}"
            if code == grpc.StatusCode.UNAUTHENTICATED:
                message += f" ({self.token_hint})"
        return RpcError(code, details, message, call, target)

    def check_reachable(self) -> None:
        """Raises RpcError unless a connection to the master is established within `timeout`."""
        self._endpoint().check_reachable(self.timeout)

    def close(self) -> None:
        """Closes the connection; the client cannot be used afterwards."""
        for e in self._endpoints:
            e.close()

    def __enter__(self) -> "MasterClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- submitting -----------------------------------------------------------------------------

    def job_spec(
        self,
        scene: str,
        *,
        width: int = 512,
        height: int = 512,
        spp: int = 16,
        paths_per_round: int = 1,
        round_growth: float = 0.25,
        seed: int = 1,
        mode: str = "skip",
        reproject: str = "gl",
        subpixels: int = 4,
        epsilon: float = 3e-4,
        min_paths: int = 1,
        reprojected_weight: float = 0.5,
        combine: str = "fixed",
        path_budget: bool = False,
        reproject_glossy: bool = False,
        joint_test: bool = True,
        rr: Optional[str] = None,
        max_depth: Optional[int] = None,
        mis: bool = True,
        tile: int = 64,
        taper_tiles: bool = False,
        eye: Optional[Sequence[float]] = None,
        look: Optional[Sequence[float]] = None,
        up: Optional[Sequence[float]] = None,
        fov: Optional[float] = None,
        name: Optional[str] = None,
        priority: int = 0,
        time_budget: Optional[float] = None,
        request_id: Optional[str] = None,
        sampler: str = "sobol-burley",
        environment: Union[None, float, Sequence[float], str, os.PathLike] = None,
        environment_strength: Optional[float] = None,
        environment_rotation: float = 0.0,
        sun: Optional[Sequence[float]] = None,
    ) -> pb.JobSpec:
        """The JobSpec submit() sends (see submit for the arguments). Uploads a file scene over the
        inline limit, which is then referred to by hash."""
        mode_value = MODES.get(mode.lower())
        if mode_value is None:
            raise ArgumentError(f"mode '{mode}' is not one of skip, rp, pt")
        method = S.METHODS.get(reproject.lower())
        if method is None:
            raise ArgumentError(f"reproject '{reproject}' is not one of gl, cpu, exact")
        rr_mode = rs_pb.RUSSIAN_ROULETTE_MODE_UNSPECIFIED if rr is None else S.ROULETTE.get(str(rr).lower())
        if rr_mode is None:
            raise ArgumentError(f"rr '{rr}' is not one of {', '.join(S.ROULETTE)}")
        combine_value = S.COMBINE.get(combine.lower())
        if combine_value is None:
            raise ArgumentError(f"combine '{combine}' is not one of fixed, variance")
        sampler_value = S.SAMPLERS.get(sampler.lower())
        if sampler_value is None:
            raise ArgumentError(f"sampler '{sampler}' is not one of sobol-burley, independent")
        camera_parts = {"eye": eye, "look": look, "up": up, "fov": fov}
        given = [k for k, v in camera_parts.items() if v is not None]
        if given and len(given) != 4:
            missing = ", ".join(k for k in camera_parts if k not in given)
            raise ArgumentError(f"a camera needs all of eye, look, up and fov (missing: {missing}); none: the scene's own")

        width, height = L.job_whole("width", width, L.IMAGE_SIDE), L.job_whole("height", height, L.IMAGE_SIDE)
        spp = L.job_whole("spp", spp, L.SPP)
        per_spp = f"between 1 and spp ({spp})"
        paths_per_round = L.whole("paths_per_round", paths_per_round, 1, spp, per_spp)
        min_paths = L.whole("min_paths", min_paths, 1, spp, per_spp)
        round_growth = L.job_real("round_growth", round_growth, L.ROUND_GROWTH)
        seed = L.whole("seed", seed, 0, L.UINT64_MAX)
        subpixels = L.job_whole("subpixels", subpixels, L.SUBPIXELS)
        epsilon = L.job_real("epsilon", epsilon, L.EPSILON)
        L.real("reprojected_weight", reprojected_weight, 0, 1, "in (0, 1]", above=True)
        if max_depth is not None:
            max_depth = L.job_whole("max_depth", max_depth, L.MAX_DEPTH)
        tile = L.job_whole("tile", tile, L.TILE_SIZE)
        priority = L.whole("priority", priority, *L.INT32)
        if time_budget is not None:
            time_budget = L.positive_seconds("time_budget", time_budget)
        if fov is not None:
            fov = L.real("fov", fov)

        env, env_image, sun_pb = S.lighting(environment, environment_strength, environment_rotation, sun)
        if env_image is not None:
            bundle, env.image = _scene.bundle_scene_with_image(scene, env_image)
        else:
            bundle = _scene.bundle_scene(scene)
        spec = pb.JobSpec(
            width=width,
            height=height,
            target_spp=spp,
            paths_per_round=paths_per_round,
            mode=mode_value,
            seed=seed,
            tile_size=tile,
            round_growth=round_growth,
            mis=mis,
            taper_tiles=taper_tiles,
            priority=priority,
            request_id=request_id or secrets.token_hex(16),
            sampler=sampler_value,
        )
        spec.reprojection.CopyFrom(
            rs_pb.ReprojectionSettings(
                method=method,
                subpixels=subpixels,
                epsilon_fraction=epsilon,
                min_paths=min_paths,
                reprojected_weight=reprojected_weight,
                combine=combine_value,
                path_budget=bool(path_budget),
                reproject_glossy=reproject_glossy,
                joint_test=joint_test,
            )
        )
        spec.russian_roulette.CopyFrom(rs_pb.RussianRouletteSettings(mode=rr_mode, max_depth=max_depth))
        # Without a camera the master takes the scene's own (a built-in's view, a scene JSON's
        # "camera", the default camera for an OBJ).
        if given:
            spec.camera.CopyFrom(
                rs_pb.Camera(eye=S.vec3("eye", eye), look=S.vec3("look", look), up=S.vec3("up", up), fov_y_degrees=fov)
            )
        if env is not None:
            spec.environment.CopyFrom(env)
        if sun_pb is not None:
            spec.sun.CopyFrom(sun_pb)
        job_name = _default_job_name(scene) if name is None else name
        if len(job_name.encode()) > L.MAX_NAME_BYTES:
            raise ArgumentError(f"job name is {len(job_name.encode())} bytes long, at most {L.MAX_NAME_BYTES}")
        spec.name = job_name
        if time_budget is not None:
            spec.time_budget_seconds = time_budget

        if bundle.builtin:
            spec.scene.builtin = bundle.builtin
        elif bundle.total_bytes > self.inline_scene_limit:
            spec.scene.uploaded_hash = self.upload_scene(bundle)
        else:
            files = spec.scene.files
            files.entry_path = bundle.entry_path
            for path, data in bundle.files:
                files.files.add(path=path, data=data)
            spec.scene.content_hash = bundle.content_hash()
        return spec

    def submit(self, scene: str, **options) -> str:
        """Queues a job and returns its id.

        Args:
            scene: "builtin:NAME[?k=v&...]", an OBJ path (sent with its MTL files and map_Kd
                textures) or a scene JSON path (with the OBJ it names).
            width, height: image size, pixels (512 x 512).
            spp: target samples per pixel P (16).
            paths_per_round: k (1); round_growth: g (0.25).
            seed: random seed (1).
            sampler: the eye paths' random numbers: "sobol-burley" (default) or "independent".
            mode: "skip" (reprojection plus pixel skipping, the default), "rp" or "pt".
            reproject: "gl" (default), "cpu" or "exact".
            subpixels (4), epsilon (3e-4), min_paths (1), reproject_glossy (False), joint_test (True).
            reprojected_weight: W in (0, 1], what a reprojected sample counts for against a traced
                path (0.5, as `epr`; `--reprojected-weight`).
            combine: "fixed" (default, W above) or "variance" (inverse-variance weights; `--combine`).
            path_budget: with the fixed rule, a pixel traces only the paths its counts say it still
                needs in a round (False, as `epr`; `--path-budget`, docs/DESIGN.md "Progressive rounds").
            rr: Russian roulette "auto", "reuse", "throughput", "albedo", "paper" or "off" (job_settings.ROULETTE);
                None (default): the master's default, auto, as `epr`. max_depth overrides its cap.
            mis: MIS for direct light (True); False: next event estimation only.
            tile: tile edge, pixels (64); taper_tiles (False).
            eye, look, up (x, y, z each) and fov (degrees): a camera, all four or none (the scene's own).
            environment: light from outside, replacing the scene's: a colour (one number, a grey, or
                r, g, b) or an equirectangular .hdr/.exr path (inside the scene's folder; anywhere with a
                built-in scene); environment_strength multiplies it, environment_rotation (degrees)
                turns an image about +Y.
            sun: (dx, dy, dz[, angle_degrees[, irradiance or r, g, b]]), replacing the scene's sun: the
                direction towards it, its angular diameter (0.53) and irradiance in W/m^2 (1).
            name: for listings (default: the scene's name); priority (0); time_budget: seconds.
            request_id: idempotency key (default: a random one, so a retried SubmitJob queues once).

        A number of the wrong type or outside its range (limits.py: epr's ranges) is ArgumentError
        naming the argument and its range, before anything is sent. What depends on the scene or
        the master (a camera, this master's limits) the master checks: INVALID_ARGUMENT with the
        reason (raised as RpcError). A broken scene file is INVALID_ARGUMENT naming file and line;
        a file that cannot be read here is SceneError.
        """
        return self.submit_spec(self.job_spec(scene, **options))

    def submit_spec(self, spec: pb.JobSpec) -> str:
        """Queues a ready JobSpec (retrying once after a deadline when it has a request_id)."""
        attempts = 2 if spec.request_id else 1
        timeout = self._scene_deadline(spec)
        for attempt in range(1, attempts + 1):
            try:
                job_id = self._endpoint().stub.SubmitJob(spec, timeout=timeout, metadata=self._metadata()).id
            except grpc.RpcError as e:
                if e.code() == grpc.StatusCode.DEADLINE_EXCEEDED and attempt < attempts:
                    log.warning("SubmitJob to %s timed out; retrying with the same request id", self.target)
                    continue
                raise self._error(e, "SubmitJob") from None
            if not job_id:
                raise RpcError(
                    grpc.StatusCode.INTERNAL,
                    "empty job id",
                    f"master at {self.target} answered SubmitJob without a job id",
                    "SubmitJob",
                    self.target,
                )
            return job_id
        raise AssertionError("unreachable")

    def check_frames(self, spec: pb.JobSpec, frames: List[int]) -> None:
        """Has the master check a batch's spec (no camera, no frame) at each of `frames` as SubmitJob
        would (CheckFrames: the scene loaded once); queues nothing. Raises RpcError with the refusal."""
        request = pb.CheckFramesRequest(spec=spec, frames=frames)
        try:
            self._endpoint().stub.CheckFrames(request, timeout=self._scene_deadline(spec), metadata=self._metadata())
        except grpc.RpcError as e:
            raise self._error(e, "CheckFrames") from None

    def _scene_deadline(self, spec: pb.JobSpec) -> float:
        """The deadline of a call that has the master load the spec's file scene before it answers:
        it grows with the scene's size."""
        scene_bytes = sum(len(f.data) for f in spec.scene.files.files)
        if spec.scene.WhichOneof("source") == "uploaded_hash":
            with self._lock:
                scene_bytes = self._uploaded_bytes.get(spec.scene.uploaded_hash, scene_bytes)
        return self.timeout + scene_bytes / self.min_scene_load_bytes_per_second

    def upload_scene(self, bundle: _scene.SceneBundle) -> str:
        """Streams a file scene to the master (UploadScene); returns its content hash."""
        if bundle.builtin:
            raise ArgumentError("built-in scenes are not uploaded")
        content_hash = bundle.content_hash()
        total = bundle.total_bytes
        self.check_reachable()

        def chunks() -> Iterator[scene_pb.SceneChunk]:
            manifest = scene_pb.SceneManifest(content_hash=content_hash, entry_path=bundle.entry_path, total_bytes=total)
            for path, data in bundle.files:
                manifest.files.add(path=path, size_bytes=len(data))
            yield scene_pb.SceneChunk(manifest=manifest)
            sent = 0
            reported = time.monotonic()
            for index, (_, data) in enumerate(bundle.files):
                for offset in range(0, len(data), CHUNK_BYTES):
                    piece = data[offset : offset + CHUNK_BYTES]
                    yield scene_pb.SceneChunk(
                        data=scene_pb.SceneFileData(file_index=index, offset=offset, data=piece)
                    )
                    sent += len(piece)
                    if self.upload_progress and time.monotonic() - reported >= 1.0:
                        reported = time.monotonic()
                        self.upload_progress(sent, total)

        timeout = self.timeout + total / self.min_transfer_bytes_per_second
        try:
            ref = self._endpoint().stub.UploadScene(chunks(), timeout=timeout, metadata=self._metadata())
        except grpc.RpcError as e:
            raise self._error(e, "UploadScene") from None
        if ref.content_hash != content_hash:
            raise RpcError(
                grpc.StatusCode.DATA_LOSS,
                "hash mismatch",
                f"master at {self.target} stored the uploaded scene as {ref.content_hash}, expected {content_hash}",
                "UploadScene",
                self.target,
            )
        with self._lock:
            self._uploaded_bytes[content_hash] = total
        if self.upload_progress:
            self.upload_progress(total, total)
        return content_hash

    # ---- queries --------------------------------------------------------------------------------

    def status(self, job_id: str) -> JobStatus:
        """The job's current status (GetJob); RpcError NOT_FOUND for an unknown job."""
        try:
            s = self._endpoint().stub.GetJob(pb.JobId(id=job_id), timeout=self.timeout, metadata=self._metadata())
        except grpc.RpcError as e:
            raise self._error(e, "GetJob") from None
        return JobStatus.from_proto(s)

    def list(
        self, states: Optional[Iterable[str]] = None, limit: int = 0, batch: Optional[str] = None
    ) -> List[JobStatus]:
        """Jobs newest first (all pages), optionally only those in `states` ("queued", "running",
        "done", "failed", "cancelled") and of the batch `batch` (submit_frames); at most `limit` (0: all)."""
        limit = L.whole("limit", limit, 0, L.UINT64_MAX, "0 (all jobs) or more")
        by_name = {v.lower(): k for k, v in STATES.items()}
        request = pb.ListJobsRequest(batch_id=batch or "")
        for state in states or ():
            if state.lower() not in by_name:
                raise ArgumentError(f"state '{state}' is not one of {', '.join(by_name)}")
            request.states.append(by_name[state.lower()])
        jobs: List[JobStatus] = []
        while True:
            request.page_size = min(100, limit - len(jobs)) if limit else 100
            try:
                response = self._endpoint().stub.ListJobs(request, timeout=self.timeout, metadata=self._metadata())
            except grpc.RpcError as e:
                raise self._error(e, "ListJobs") from None
            # A master that does not filter by batch lists every job.
            jobs.extend(JobStatus.from_proto(j) for j in response.jobs if not batch or j.batch_id == batch)
            if limit and len(jobs) >= limit:
                return jobs[:limit]
            # An empty or repeated token ends the listing (a repeated one would loop forever).
            if not response.next_page_token or response.next_page_token == request.page_token:
                return jobs
            request.page_token = response.next_page_token

    def cancel(self, job_id: str) -> JobStatus:
        """Stops a job; returns its status after the call (unchanged for a job that had ended). The
        results of its last committed round stay fetchable (get(..., partial=True) not needed)."""
        try:
            s = self._endpoint().stub.CancelJob(pb.JobId(id=job_id), timeout=self.timeout, metadata=self._metadata())
        except grpc.RpcError as e:
            raise self._error(e, "CancelJob") from None
        return JobStatus.from_proto(s)

    # ---- watching -------------------------------------------------------------------------------

    def watch(self, job_id: str, min_interval_ms: int = 0) -> Iterator[JobStatus]:
        """The job's status now, then after every committed round and state change, until the job
        ends (the last status yielded is terminal). Stopping the iteration (break, close()) cancels
        the call. min_interval_ms spaces updates (state changes always come).

        Each WatchJob call runs for at most watch_call_timeout and is then re-issued; if the master
        goes away mid-watch (a restart: jobs resume from their checkpoint), the watch reconnects for
        up to watch_reconnect_timeout. Raises RpcError for an unknown job or an unreachable master.
        """
        min_interval_ms = L.whole("min_interval_ms", min_interval_ms, 0, L.UINT32_MAX)
        request = pb.WatchJobRequest(job_id=job_id, min_interval_ms=min_interval_ms)
        self.check_reachable()  # the first call must not wait out watch_call_timeout on a silent address
        last: Optional[pb.JobStatus] = None
        lost_since: Optional[float] = None  # the master went away mid-watch at this time
        while True:
            timeout = self.watch_call_timeout
            if lost_since is not None:
                left = lost_since + self.watch_reconnect_timeout - time.monotonic()
                timeout = max(0.001, min(timeout, left))
            call = self._endpoint().stub.WatchJob(
                request, timeout=timeout, metadata=self._metadata(), wait_for_ready=lost_since is not None
            )
            code: Optional[grpc.StatusCode] = None
            details = ""
            try:
                for status in call:
                    last = status
                    lost_since = None
                    yield JobStatus.from_proto(status)
            except grpc.RpcError as e:
                code, details = e.code(), e.details() or ""
            finally:
                call.cancel()  # also when the caller stops iterating
            if last is not None and last.state in TERMINAL_STATES:
                return
            if code == grpc.StatusCode.DEADLINE_EXCEEDED and last is not None and lost_since is None:
                continue  # refresh the call
            # The stream ended without the job's end, or with a failure a later call may not meet
            # again (the master away, busy or restarting); any other error is final.
            went_away = code is None or code in TRANSIENT_CODES
            if last is None or not went_away:
                if code is None:
                    code, details = grpc.StatusCode.UNAVAILABLE, "stream ended early"
                raise self._status_error(code, details, "WatchJob")
            code_name = code.name if code is not None else "OK"
            if lost_since is None:
                lost_since = time.monotonic()
                log.warning(
                    "lost the watch of job %s at %s (%s); reconnecting for up to %g s",
                    job_id,
                    self.target,
                    code_name,
                    self.watch_reconnect_timeout,
                )
            elif time.monotonic() - lost_since >= self.watch_reconnect_timeout:
                raise RpcError(
                    code or grpc.StatusCode.UNAVAILABLE,
                    details or "stream ended early",
                    f"lost master at {self.target} while watching job {job_id} and could not reconnect within "
                    f"{self.watch_reconnect_timeout:g} s ({code_name})",
                    "WatchJob",
                    self.target,
                )
            time.sleep(0.2)  # no hot loop on a master that ends streams at once

    def wait(self, job_id: str, on_status: Optional[Callable[[JobStatus], None]] = None) -> JobStatus:
        """Watches the job to its end (calling on_status with every status) and returns the last."""
        last = None
        for status in self.watch(job_id):
            last = status
            if on_status:
                on_status(status)
        assert last is not None  # watch yields at least the terminal status or raises
        return last

    # ---- results --------------------------------------------------------------------------------

    def _fetch(
        self, job_id: str, kind: ResultKind, partial: bool, begin: Callable[[pb.ResultHeader], Callable[[bytes], None]]
    ) -> pb.ResultHeader:
        """Streams one result (FetchResult): begin(header) returns the writer of its bytes. Checks
        the offsets, the total size and the SHA-256 the header announces."""
        call_name = f"FetchResult({pb.ResultKind.Name(kind.proto).removeprefix('RESULT_KIND_')})"
        self.check_reachable()
        request = pb.ResultRequest(job_id=job_id, kind=kind.proto, allow_partial=partial)
        call = self._endpoint().stub.FetchResult(request, timeout=self.transfer_timeout, metadata=self._metadata())

        def bad_stream(why: str) -> RpcError:
            return RpcError(
                grpc.StatusCode.DATA_LOSS,
                why,
                f"master at {self.target} sent a bad {call_name} stream for job {job_id}: {why}",
                call_name,
                self.target,
            )

        header: Optional[pb.ResultHeader] = None
        write: Optional[Callable[[bytes], None]] = None
        received = 0
        sha = hashlib.sha256()
        try:
            for chunk in call:
                if header is None:
                    if chunk.WhichOneof("part") != "header":
                        raise bad_stream("the first message is not the header")
                    header = chunk.header
                    write = begin(header)
                    continue
                if chunk.WhichOneof("part") != "data":
                    raise bad_stream("a second header")
                data = chunk.data
                if data.offset != received:
                    raise bad_stream(f"data at offset {data.offset}, expected {received}")
                if len(data.data) > header.total_bytes - received:
                    raise bad_stream(f"more than the {header.total_bytes} bytes announced")
                received += len(data.data)
                sha.update(data.data)
                write(data.data)
        except grpc.RpcError as e:
            raise self._error(e, call_name) from None
        finally:
            call.cancel()
        if header is None:
            raise bad_stream("no header")
        if received != header.total_bytes:
            raise bad_stream(f"{received} bytes received, {header.total_bytes} announced")
        if sha.hexdigest() != header.sha256.lower():
            raise bad_stream(f"SHA-256 {sha.hexdigest()} does not match the announced {header.sha256}")
        return header

    def fetch_bytes(self, job_id: str, kind: Union[str, ResultKind] = "exr", partial: bool = False) -> ResultBytes:
        """One result in memory. kind: "exr", "png", "json", "pathtrace.exr", "counts.exr",
        "reprojection.exr", "samples.exr" or "samples.png". partial: also a running job's latest
        committed round."""
        k = result_kind(kind)
        parts: List[bytes] = []
        header = self._fetch(job_id, k, partial, lambda h: parts.append)
        return ResultBytes(k.name, b"".join(parts), header.media_type, header.round, header.partial)

    def fetch(self, job_id: str, kind: Union[str, ResultKind], path: str, partial: bool = False) -> FetchedFile:
        """Downloads one result to `path` atomically (a temporary file beside it, then renamed)."""
        k = result_kind(kind)
        folder = os.path.dirname(path)
        if folder:
            os.makedirs(folder, exist_ok=True)
        tmp = f"{path}.part-{os.getpid()}-{secrets.token_hex(4)}"
        try:
            with open(tmp, "xb") as out:
                header = self._fetch(job_id, k, partial, lambda h: out.write)
            os.replace(tmp, path)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise
        return FetchedFile(k.name, path, header.total_bytes, header.round, header.partial)

    def _check_results(self, job_id: str, partial: bool) -> JobStatus:
        """The job's status if its results can be had, else JobError (as `epr get` refuses)."""
        status = self.status(job_id)
        if status.state == "FAILED":
            raise JobError(f"job {job_id} FAILED: {status.error_message}", job_id, status.state, status.error_message)
        if not status.terminal and not partial:
            rounds = f"{status.round}/{status.rounds_planned}" if status.rounds_planned else f"{status.round}"
            raise JobError(
                f"job {job_id} is {status.state} (round {rounds}): its results exist once it ends; "
                "partial=True fetches the latest committed round",
                job_id,
                status.state,
            )
        return status

    def _each_kind(self, job_id: str, kinds: Sequence[ResultKind], fetch_one):
        """fetch_one(kind) for each kind, skipping those the job did not produce: NOT_FOUND or
        FAILED_PRECONDITION (not made by its mode) and INVALID_ARGUMENT (unknown to an older master),
        except for the EXR, whose error is raised."""
        out = []
        for k in kinds:
            try:
                out.append(fetch_one(k))
            except RpcError as e:
                absent = e.code in (
                    grpc.StatusCode.NOT_FOUND,
                    grpc.StatusCode.FAILED_PRECONDITION,
                    grpc.StatusCode.INVALID_ARGUMENT,
                )
                if k.proto == pb.RESULT_KIND_EXR or not absent:
                    raise
                log.debug("job %s has no %s result: %s", job_id, k.name, e)
        return out

    def get(
        self, job_id: str, out: Optional[str] = None, *, partial: bool = False, as_arrays: bool = False
    ) -> Union[List[FetchedFile], Dict[str, numpy.ndarray]]:
        """A job's results, as `epr get` fetches them.

        Files (the default): PREFIX.exr, .png, .json, .pathtrace.exr, .counts.exr and, when the job
        reprojected, .reprojection.exr, .samples.exr and .samples.png, PREFIX = `out` (default: the
        job id); returns the FetchedFile list.

        as_arrays=True: the EXR images as float32 numpy arrays of shape (height, width, channels),
        by name: "combined" (RGB), "pathtrace" (RGB), "counts" (M, M'), and when reprojected
        "reprojection" (RGB) and "samples" (M'). Decoded with OpenImageIO (python3-openimageio).

        A FAILED job, or one that has not ended (without partial=True), raises JobError.
        """
        self._check_results(job_id, partial)
        if as_arrays:
            kinds = [k for k in RESULT_KINDS if k.array]
            results = self._each_kind(job_id, kinds, lambda k: (k, self.fetch_bytes(job_id, k, partial)))
            return {k.array: decode_exr(r.data) for k, r in results}
        prefix = job_id if out is None else out
        if err := output_prefix_error(prefix):
            raise ArgumentError(f"out: {err}")
        return self._each_kind(job_id, RESULT_KINDS, lambda k: self.fetch(job_id, k, prefix + k.suffix, partial))
