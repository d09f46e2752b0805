"""Run inside Blender with its UI (under xvfb-run): renders as a user does with F12 and Render
Animation, where Blender runs the render engine in a job thread, and saves what it got.

    blender --python-expr ENABLE_ADDON scene.blend --python ui_render.py -- --still OUT.exr --frames OUT_####
        --batch OUT_####

The still is the Render Result saved as EXR (linear); the animation writes the scene's frame range
to --frames; then Render Frames on Farm (invoked as the panel's button does: a timer follows the
batch) writes it to --batch. Last, F12 of a job too long to wait for (1000000 spp): once the farm
runs it, Blender quits, which stops the render and must cancel the farm job. Prints "ui_render: ..."
lines, then quits (also after 240 s: "ui_render: timeout", and after an error it does not expect).
"""

import sys
import time

import bpy

argv = sys.argv[sys.argv.index("--") + 1 :]
still = argv[argv.index("--still") + 1]
frames = argv[argv.index("--frames") + 1]
batch_frames = argv[argv.index("--batch") + 1]
steps = ["still", "wait_still", "animation", "wait_animation", "batch", "wait_batch", "long", "wait_long"]
LONG_SPP = 1000000
started = time.monotonic()


def say(message):
    print(f"ui_render: {message}", flush=True)


def quit_blender():
    bpy.context.preferences.use_preferences_save = False
    bpy.ops.wm.quit_blender()


def tick():
    """One step of the script; never raises: a timer whose function raises is unregistered, and
    Blender would then sit idle until killed."""
    if time.monotonic() - started > 240:
        say("timeout")
        quit_blender()
        return None
    try:
        return step_once()
    except Exception as e:
        # Blender's guard against writes from read-only Python callbacks is one flag for all its
        # threads: under load a write here was refused right after Render Animation ended ("Writing
        # to ID classes in this context is not allowed"). A step runs again until it is done.
        if "not allowed" in str(e):
            say(f"{steps[0]}: {e}; again")
            return 0.25
        say(f"{steps[0]} failed: {e!r}")
        quit_blender()
        return None


def step_once():
    step = steps[0]
    if step == "wait_batch":
        from eprfarm_blender import batch

        if batch.ACTIVE:
            return 0.25
        say("batch finished")
        steps.pop(0)
        return 0.1
    if step == "wait_long":
        from eprfarm_blender import settings

        with settings.import_client().Client(bpy.context.scene.eprfarm.master) as client:
            running = [j for j in client.list(states=["running"]) if j.target_spp == LONG_SPP]
        if not running:
            return 0.25
        say(f"quitting while {running[0].id} runs")
        quit_blender()
        return None
    if step.startswith("wait"):
        if bpy.app.is_job_running("RENDER"):
            return 0.25
        steps.pop(0)
        if step == "wait_still":
            bpy.data.images["Render Result"].save_render(still)
            say(f"still saved {still}")
        else:
            say("animation finished")
        return 0.1
    if step == "still":
        say("F12")
        say(f"invoke: {bpy.ops.render.render('INVOKE_DEFAULT')}")
    elif step == "animation":
        bpy.context.scene.render.filepath = frames
        say("render animation")
        say(f"invoke: {bpy.ops.render.render('INVOKE_DEFAULT', animation=True)}")
    elif step == "batch":
        bpy.context.scene.render.filepath = batch_frames
        say("render frames on farm")
        say(f"invoke: {bpy.ops.eprfarm.render_frames('INVOKE_DEFAULT')}")
    else:
        bpy.context.scene.eprfarm.samples = LONG_SPP
        say("F12 of a long job")
        say(f"invoke: {bpy.ops.render.render('INVOKE_DEFAULT')}")
    steps.pop(0)
    return 0.25


bpy.app.timers.register(tick, first_interval=1.0)
