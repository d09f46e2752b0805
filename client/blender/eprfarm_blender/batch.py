"""A frame range as one farm batch: every frame exported and queued at once (the farm renders them
side by side), then followed until each is done, its image saved at the scene's output path and the
frames loaded as one image sequence."""

import os
import secrets
import shutil
import sys
import tempfile
import time

import bpy

from . import export, settings

POLL_SECONDS = 1.0


class BatchError(Exception):
    """A batch that cannot be submitted or followed; the message is shown as it is."""


def frame_file(scene, frame):
    """Where a frame's EXR goes: the scene's output path for the frame, with the .exr extension."""
    path = bpy.path.abspath(scene.render.frame_path(frame=frame))
    return os.path.splitext(path)[0] + ".exr"


class FarmBatch:
    """The frames of one submission and what became of them."""

    def __init__(self, context, warn):
        self.scene = context.scene
        self.frames = list(range(self.scene.frame_start, self.scene.frame_end + 1, self.scene.frame_step))
        self.warn = warn
        self.eprfarm = settings.import_client()  # ImportError says what to do
        s = self.scene.eprfarm
        try:
            self.client = settings.farm_client(self.eprfarm, s)
        except ValueError as e:
            raise BatchError(str(e)) from None
        self.batch_id = "b-" + secrets.token_hex(6)
        self.name = os.path.splitext(os.path.basename(bpy.data.filepath))[0] or "untitled"
        self.jobs = {}  # frame -> job id
        self.done = {}  # frame -> file written
        self.failed = {}  # frame -> reason
        self.status_line = ""
        self.image = None

    def submit(self, context):
        """Exports and queues every frame (the scene's frame is put back afterwards)."""
        scene, s = self.scene, self.scene.eprfarm
        width, height = export.resolution(scene)
        folder = tempfile.mkdtemp(prefix="eprfarm-batch-")
        current = scene.frame_current
        uploaded = {}  # content hash of a large scene -> its uploaded hash
        limit = self.client.inline_scene_limit
        frames_module = self.eprfarm.frames
        window, runs, still = 0, [], None  # still: the first frame's scene content hash
        try:
            for index, frame in enumerate(self.frames):
                scene.frame_set(frame)
                depsgraph = context.evaluated_depsgraph_get()
                camera, warnings = export.farm_camera(scene, depsgraph)
                frame_folder = os.path.join(folder, str(frame))
                os.mkdir(frame_folder)
                lighting, more = export.farm_lighting(scene, depsgraph, frame_folder)
                if index == 0:
                    for w in warnings + export.scene_warnings(scene, depsgraph) + more:
                        self.warn(w)
                job_scene = export.scene_file(export.export_gltf(scene, context.view_layer, frame_folder), lighting)
                self.client.inline_scene_limit = float("inf")  # bundled here; a large one uploaded once below
                try:
                    spec = self.client.job_spec(
                        job_scene, width=width, height=height, spp=s.samples, mode=s.mode, seed=s.seed,
                        eye=camera.eye, look=camera.look, up=camera.up, fov=camera.fov,
                        name=f"{self.name}.{frame:04d}",
                    )  # fmt: skip
                finally:
                    self.client.inline_scene_limit = limit
                if index == 0:
                    try:
                        window, run = frames_module.checked_window(s.frame_window, None, spec)
                    except ValueError as e:
                        raise BatchError(str(e)) from None
                    runs = frames_module.run_frames(self.frames, run)
                    still = spec.scene.content_hash
                if window:
                    if spec.scene.content_hash != still:
                        raise BatchError(
                            f"frame {frame}: the scene is not the same as at frame {self.frames[0]} (objects, "
                            "materials or lights move): a frame window needs a still scene; set Frame Window to 0"
                        )
                    spec.frame_window = window
                    spec.window_first, spec.window_last = runs[index]
                    spec.seed = s.seed + frame  # the frames of a run trace paths of their own
                scene_bytes = sum(len(f.data) for f in spec.scene.files.files)
                if scene_bytes > limit:
                    content_hash = spec.scene.content_hash
                    if content_hash not in uploaded:
                        uploaded[content_hash] = self.client.upload_scene(self.eprfarm.bundle_scene(job_scene))
                    spec.scene.CopyFrom(type(spec.scene)(uploaded_hash=uploaded[content_hash]))
                spec.batch_id = self.batch_id
                spec.batch_name = self.name
                spec.frame = frame
                spec.batch_frames = len(self.frames)
                spec.request_id = f"{self.batch_id}-{frame}"
                self.jobs[frame] = self.client.submit_spec(spec)
                self.status_line = f"eprfarm: batch {self.batch_id}: {index + 1}/{len(self.frames)} frames queued"
                shutil.rmtree(frame_folder, ignore_errors=True)
        finally:
            scene.frame_set(current)
            shutil.rmtree(folder, ignore_errors=True)
        print(f"eprfarm: batch {self.batch_id}: {len(self.jobs)} frames queued at {s.master}", flush=True)

    def step(self):
        """Looks at the batch once: saves and loads the frames that finished. True when every frame has ended."""
        statuses = {j.frame: j for j in self.client.list(batch=self.batch_id) if j.frame in self.jobs}
        percent = 0.0
        for frame, job in self.jobs.items():
            status = statuses.get(frame)
            if frame in self.done or frame in self.failed:
                percent += 100.0
                continue
            if status is None:
                continue
            if status.state == "DONE":
                path = frame_file(self.scene, frame)
                try:
                    os.makedirs(os.path.dirname(path), exist_ok=True)
                    self.client.fetch(job, "exr", path)
                except OSError as e:
                    raise BatchError(f"frame {frame}: cannot save {path}: {e.strerror or e}") from None
                self.done[frame] = path
                print(f"eprfarm: frame {frame}: job {job} done, saved {path}", flush=True)
                self._load(frame)
            elif status.terminal:
                self.failed[frame] = f"job {job} {status.state.lower()}: {status.error_message or 'no reason given'}"
                self.warn(f"frame {frame}: {self.failed[frame]}")
            percent += status.percent if not status.terminal else 100.0
        ended = len(self.done) + len(self.failed)
        self.status_line = (
            f"eprfarm: batch {self.batch_id}: {len(self.done)}/{len(self.jobs)} frames done"
            + (f", {len(self.failed)} failed" if self.failed else "")
            + f", {percent / max(1, len(self.jobs)):.0f}%"
        )
        return ended == len(self.jobs)

    def _load(self, frame):
        """The finished frames as one image sequence named after the batch (its first frame's file)."""
        first = min(self.done)
        if self.image is None or first == frame:
            if self.image is not None:
                bpy.data.images.remove(self.image)
            self.image = bpy.data.images.load(self.done[first], check_existing=False)
            self.image.name = f"eprfarm {self.name}"
            self.image.source = "SEQUENCE" if len(self.frames) > 1 else "FILE"

    def cancel(self):
        for frame, job in self.jobs.items():
            if frame not in self.done and frame not in self.failed:
                try:
                    self.client.cancel(job)
                except self.eprfarm.EprError as e:
                    self.warn(f"frame {frame}: cancel: {e}")

    def close(self):
        self.client.close()


ACTIVE = {}  # scene name -> the FarmBatch a timer follows (UI)


def _reported(e):
    """True for the errors an operator reports in words: the add-on's, the export's and the client's."""
    eprfarm = sys.modules.get("eprfarm")
    return isinstance(e, (ImportError, BatchError, export.ExportError)) or (
        eprfarm is not None and isinstance(e, eprfarm.EprError)
    )


def _redraw():
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "PROPERTIES":
                area.tag_redraw()


class EPRFARM_OT_render_frames(bpy.types.Operator):
    """Queue the scene's frame range on the farm as one batch (rendered side by side); each frame is
    saved as EXR at the output path when it is done and the frames are loaded as an image sequence"""

    bl_idname = "eprfarm.render_frames"
    bl_label = "Render Frames on Farm"
    bl_options = {"REGISTER"}

    def _start(self, context):
        def warn(message):
            self.report({"WARNING"}, f"eprfarm: {message}")

        batch = None
        try:
            batch = FarmBatch(context, warn)
            batch.submit(context)
        except Exception as e:
            if not _reported(e):
                raise
            self._fail(batch, e)
            return None
        return batch

    def _fail(self, batch, error):
        """Reports `error` (the operator then returns CANCELLED; a script's call raises RuntimeError
        with the message) after cancelling the frames of `batch` that have not ended."""
        message = f"eprfarm: {error}"
        if batch is not None:
            if batch.jobs:
                batch.cancel()
                message = f"eprfarm: batch {batch.batch_id}: {error}; its frames that had not ended were cancelled"
            batch.close()
        self.report({"ERROR"}, message)

    def execute(self, context):
        """Submits, then follows the batch to its end here (background Blender, scripts)."""
        batch = self._start(context)
        if batch is None:
            return {"CANCELLED"}
        shown = ""
        try:
            while not batch.step():
                if batch.status_line != shown:
                    shown = batch.status_line
                    print(shown, flush=True)
                time.sleep(POLL_SECONDS)
        except Exception as e:
            if not _reported(e):
                batch.close()
                raise
            self._fail(batch, e)
            return {"CANCELLED"}
        batch.close()
        print(batch.status_line, flush=True)
        if batch.failed:
            self.report({"ERROR"}, f"eprfarm: {len(batch.failed)} of {len(batch.jobs)} frames failed")
            return {"CANCELLED"}
        return {"FINISHED"}

    def invoke(self, context, event):
        """Submits, then follows the batch with a timer: Blender stays usable meanwhile."""
        if context.scene.name in ACTIVE:
            self.report({"ERROR"}, "eprfarm: this scene's batch is still running (Cancel Farm Frames stops it)")
            return {"CANCELLED"}
        batch = self._start(context)
        if batch is None:
            return {"CANCELLED"}
        scene_name = context.scene.name
        ACTIVE[scene_name] = batch

        def poll():
            try:
                finished = batch.step()
            except Exception as e:
                batch.status_line = f"eprfarm: batch {batch.batch_id}: {e}"
                finished = True
            _redraw()
            if finished:
                ACTIVE.pop(scene_name, None)
                batch.close()
                print(batch.status_line, flush=True)
                return None
            return POLL_SECONDS

        bpy.app.timers.register(poll, first_interval=POLL_SECONDS)
        return {"FINISHED"}


class EPRFARM_OT_cancel_frames(bpy.types.Operator):
    """Cancel the farm jobs of this scene's running batch"""

    bl_idname = "eprfarm.cancel_frames"
    bl_label = "Cancel Farm Frames"

    @classmethod
    def poll(cls, context):
        return context.scene.name in ACTIVE

    def execute(self, context):
        batch = ACTIVE.get(context.scene.name)
        if batch is not None:
            batch.cancel()
        return {"FINISHED"}


def status_line(scene):
    """The running batch's progress for the panel, or ""."""
    batch = ACTIVE.get(scene.name)
    return batch.status_line if batch is not None else ""


classes = (EPRFARM_OT_render_frames, EPRFARM_OT_cancel_frames)
