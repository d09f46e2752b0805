"""The render engine: each frame is exported, submitted as one farm job, watched and loaded back."""

import os
import queue
import shutil
import tempfile
import threading
import time

import bpy

from . import batch, export, settings

PREVIEW_INTERVAL = 2.0  # seconds between loads of a running job's latest round


class FarmFailure(Exception):
    """A render that cannot go on; the message is shown in Blender as it is."""


class EprfarmRenderEngine(bpy.types.RenderEngine):
    bl_idname = "EPRFARM"
    bl_label = "eprfarm"
    bl_use_preview = False
    bl_use_postprocess = True

    def render(self, depsgraph):
        scene = depsgraph.scene
        width, height = export.resolution(scene)
        result = self.begin_result(0, 0, width, height, layer=depsgraph.view_layer.name)
        folder = tempfile.mkdtemp(prefix="eprfarm-blender-")
        try:
            self._render(scene, depsgraph, width, height, result, folder)
        except FarmFailure as e:
            self._fail(str(e))
        except Exception as e:  # an error of the client package: its words, not a traceback
            eprfarm = _imported_client()
            if eprfarm is not None and isinstance(e, eprfarm.EprError):
                self._fail(str(e))
            else:
                raise
        finally:
            self.end_result(result)
            shutil.rmtree(folder, ignore_errors=True)

    def _fail(self, message):
        message = f"eprfarm: {message}"
        self.report({"ERROR"}, message)
        self.error_set(message)
        self.update_stats("", message)

    def _warn(self, message):
        self.report({"WARNING"}, f"eprfarm: {message}")

    def _render(self, scene, depsgraph, width, height, result, folder):
        s = scene.eprfarm
        try:
            eprfarm = settings.import_client()
        except ImportError as e:
            raise FarmFailure(str(e)) from None
        frame = scene.frame_current
        self.update_stats("", f"eprfarm: exporting frame {frame}")
        try:
            camera, warnings = export.farm_camera(scene, depsgraph)
            warnings += export.scene_warnings(scene, depsgraph)
            lighting, more = export.farm_lighting(scene, depsgraph, folder)
            warnings += more
            gltf = self._export(scene, depsgraph.view_layer, frame, folder)
        except export.ExportError as e:
            raise FarmFailure(str(e)) from None
        if gltf is None:
            return  # cancelled in Blender
        job_scene = export.scene_file(gltf, lighting)
        for w in warnings:
            self._warn(w)
        blend = os.path.splitext(os.path.basename(bpy.data.filepath))[0] or "untitled"
        try:
            client = settings.farm_client(eprfarm, s)
        except ValueError as e:  # a malformed address or token
            raise FarmFailure(str(e)) from None
        try:
            self.update_stats("", f"eprfarm: submitting frame {frame} to {s.master}")
            job = client.submit(
                job_scene,
                width=width,
                height=height,
                spp=s.samples,
                mode=s.mode,
                seed=s.seed,
                eye=camera.eye,
                look=camera.look,
                up=camera.up,
                fov=camera.fov,
                name=f"{blend}.{frame:04d}",
            )
            print(f"eprfarm: frame {frame}: job {job} at {s.master}", flush=True)
            last = self._watch(client, job, frame, result, folder, s.show_rounds)
            if last is None:
                return  # cancelled in Blender
            if last.state != "DONE":
                raise FarmFailure(f"job {job} {last.state.lower()}: {last.error_message or 'no reason given'}")
            self._load(client, job, result, folder, partial=False)
            self.update_progress(1.0)
            self.update_stats("", f"eprfarm: frame {frame}: job {job} done, {last.spp_mean:.1f} spp")
        finally:
            client.close()

    def _export(self, scene, view_layer, frame, folder):
        """The frame's glTF. Blender's exporter needs the main thread's context: `blender -b` renders
        there, but the UI renders in a job thread, which hands the export to the main thread (a
        timer) and waits. None when Blender asked to stop meanwhile."""
        if threading.current_thread() is threading.main_thread():
            return export.export_gltf(scene, view_layer, folder)
        done = threading.Event()
        out = {}

        def run():
            try:
                # The view layer's depsgraph follows an animation render's frame only when set.
                scene.frame_set(frame)
                out["path"] = export.export_gltf(scene, view_layer, folder)
            except Exception as e:  # raised in the render thread below
                out["error"] = e
            done.set()
            return None

        bpy.app.timers.register(run)
        while not done.wait(0.1):
            if self.test_break():
                return None
        if "error" in out:
            raise out["error"]
        return out["path"]

    def _watch(self, client, job, frame, result, folder, show_rounds):
        """Follows the job to its end: progress and stats in Blender, the latest round in the render
        result. The last status, or None when Blender asked to stop (the job is cancelled)."""
        statuses = queue.Queue()

        def follow():
            try:
                for status in client.watch(job):
                    statuses.put(status)
            except Exception as e:  # handed to the render loop
                statuses.put(e)

        threading.Thread(target=follow, daemon=True).start()
        last = None
        shown_round = 0
        shown_at = 0.0
        while last is None or not last.terminal:
            if self.test_break():
                client.cancel(job)
                print(f"eprfarm: frame {frame}: job {job} cancelled", flush=True)
                return None
            try:
                item = statuses.get(timeout=0.2)
            except queue.Empty:
                continue
            if isinstance(item, Exception):
                raise item
            last = item
            self.update_progress(min(1.0, last.percent / 100.0))
            self.update_stats(
                "",
                f"eprfarm: frame {frame}: job {job} {last.state.lower()}, round {last.round}/{last.rounds_planned}, "
                f"{last.percent:.0f}%, {last.spp_mean:.1f} spp",
            )
            if (
                show_rounds
                and last.state == "RUNNING"
                and last.round > shown_round
                and time.monotonic() - shown_at >= PREVIEW_INTERVAL
            ):
                shown_round, shown_at = last.round, time.monotonic()
                self._load(client, job, result, folder, partial=True)
        return last

    def _load(self, client, job, result, folder, partial):
        """The job's image (its latest round when partial) into the render result."""
        image = client.fetch_bytes(job, "exr", partial=partial)
        path = os.path.join(folder, "round.exr" if partial else "result.exr")
        with open(path, "wb") as f:
            f.write(image.data)
        result.layers[0].load_from_file(path)
        self.update_result(result)


def _imported_client():
    import sys

    return sys.modules.get("eprfarm")


# Material panels Eevee's engine owns that edit what the export reads: the material slots, the
# surface's node (Principled BSDF, Emission) and the blend mode (Alpha Clip is written as a cut-out).
MATERIAL_PANELS = ("EEVEE_MATERIAL_PT_context_material", "EEVEE_MATERIAL_PT_surface", "EEVEE_MATERIAL_PT_settings")


def _compatible_panels():
    """The standard panels that apply to any engine (output, format, frame range, ...) and the
    material panels above."""
    exclude = {"VIEWLAYER_PT_filter", "VIEWLAYER_PT_layer_passes"}
    panels = [
        p
        for p in bpy.types.Panel.__subclasses__()
        if "BLENDER_RENDER" in getattr(p, "COMPAT_ENGINES", ()) and p.__name__ not in exclude
    ]
    panels += [getattr(bpy.types, name) for name in MATERIAL_PANELS if hasattr(bpy.types, name)]
    return panels


class RENDER_PT_eprfarm(bpy.types.Panel):
    bl_label = "eprfarm"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    COMPAT_ENGINES = {"EPRFARM"}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES

    def draw(self, context):
        s = context.scene.eprfarm
        layout = self.layout
        layout.use_property_split = True
        layout.prop(s, "master")
        layout.prop(s, "token")
        layout.prop(s, "token_file")
        row = layout.row()
        row.prop(s, "tls")
        layout.prop(s, "ca_file")
        layout.separator()
        layout.prop(s, "samples")
        layout.prop(s, "mode")
        layout.prop(s, "seed")
        layout.prop(s, "show_rounds")
        layout.separator()
        layout.prop(s, "frame_window")
        row = layout.row(align=True)
        row.operator("eprfarm.render_frames", icon="RENDER_ANIMATION")
        row.operator("eprfarm.cancel_frames", text="", icon="CANCEL")
        line = batch.status_line(context.scene)
        if line:
            layout.label(text=line)
        col = layout.column(align=True)
        col.label(text="Exports meshes, materials, the World", icon="INFO")
        col.label(text="(colour or HDR image) and the lamps:")
        col.label(text="sun, point, spot, area (a spot's radius ignored)")


def register_panels():
    bpy.utils.register_class(RENDER_PT_eprfarm)
    for p in _compatible_panels():
        p.COMPAT_ENGINES.add("EPRFARM")


def unregister_panels():
    for p in _compatible_panels():
        p.COMPAT_ENGINES.discard("EPRFARM")
    bpy.utils.unregister_class(RENDER_PT_eprfarm)
