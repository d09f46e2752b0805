"""eprfarm: a Python client for the eprfarm render farm's masters (epr.v1.JobService).

    import eprfarm
    c = eprfarm.Client("localhost:50051")    # or several: "m1:50051,m2:50051", as `epr --master`
    job = c.submit("builtin:cornell", width=256, height=256, spp=64)
    for status in c.watch(job):
        print(status.state, status.round, f"{status.percent:.0f}%")
    c.get(job, out="cornell")                # cornell.exr, cornell.png, cornell.json, ...
    images = c.get(job, as_arrays=True)      # {"combined": numpy float32 (H, W, 3), ...}

See client.MasterClient for the options (token, TLS, deadlines), farm.Client for several masters
and errors.EprError for the errors.
"""

from .client import MasterClient
from .farm import Client, JobList, job_id_master
from .masters import MasterEndpoint, master_endpoints
from .status import RESULT_KINDS, FetchedFile, JobStatus, ResultBytes, ResultKind, decode_exr
from .errors import ArgumentError, EprError, JobError, RpcError, SceneError, TokenError
from .scene import SceneBundle, bundle_scene, bundle_scene_with_image

__all__ = [
    "Client",
    "MasterClient",
    "JobList",
    "job_id_master",
    "MasterEndpoint",
    "master_endpoints",
    "JobStatus",
    "FetchedFile",
    "ResultBytes",
    "ResultKind",
    "RESULT_KINDS",
    "decode_exr",
    "EprError",
    "ArgumentError",
    "RpcError",
    "JobError",
    "SceneError",
    "TokenError",
    "SceneBundle",
    "bundle_scene",
    "bundle_scene_with_image",
]
