"""Blender Cycles renders of one scene at a sweep of sample counts, each timed (for docs/RESULTS.md).

Run with Blender (Debian's Blender 3.4.1), usually from scripts/bench.sh:

    blender -b --factory-startup -noaudio -P scripts/cycles_sweep.py -- \
        --obj OBJDIR/cornell.obj --camera OBJDIR/cornell.camera \
        --width 512 --height 512 --spp 1,2,4,8,16,32,64 --threads 2 --outdir out/cycles/cornell_512x512

The scene is built exactly as scripts/cycles_reference.py builds it (its functions are reused:
Lambertian Diffuse BSDF from Kd, Emission strength 1 of colour Ke, black world, box pixel filter one
pixel wide, no clamping / denoising / adaptive sampling / light tree, 1024-bounce caps, pinhole camera
with a vertical field of view). The OBJ, MTL and camera come from `speed_accuracy --export-obj`.
With --adaptive, Cycles' own adaptive sampling is on (`use_adaptive_sampling`, Blender's default noise
threshold 0.01 and automatic minimum sample count): each --spp value is then the maximum sample count,
and pixels that Cycles judges converged stop earlier.

The scene is built once; every sample count is then one bpy.ops.render.render call in the same
Blender process (seed --seed for all), after one unrecorded 1-sample warm-up render (Cycles' kernel
and Blender's render pipeline initialise on the first render; eprfarm's timings include no process
start-up either). Per render it records:
  wall_s   wall seconds of the render call, Cycles' scene sync and BVH build included (Blender
           reports them only in its log, so they are not subtracted; eprfarm's times likewise
           include scene load and BVH build);
  cpu_s    CPU seconds of the Blender process during the call (getrusage, all threads).
Outputs OUTDIR/spp_N.exr (linear float RGB, row 0 at the top) and OUTDIR/times.csv
(spp,wall_s,cpu_s,file), then an empty OUTDIR/done.
"""

import argparse
import os
import resource
import shlex
import sys
import time

import bpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cycles_reference as cr  # noqa: E402  (needs bpy, so after it)


def cpu_seconds():
    u = resource.getrusage(resource.RUSAGE_SELF)
    return u.ru_utime + u.ru_stime


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    ap = argparse.ArgumentParser(prog="blender -b --factory-startup -noaudio -P scripts/cycles_sweep.py --")
    ap.add_argument("--obj")
    ap.add_argument("--gltf", help="instead of --obj: a glTF file, imported as cycles_reference.py --gltf does")
    ap.add_argument("--env", default="", help="a sky, as cycles_reference.py --env")
    ap.add_argument("--env-strength", type=float, default=1.0)
    ap.add_argument("--env-rotation", type=float, default=0.0)
    ap.add_argument("--sun", default="", help="a sun, as cycles_reference.py --sun")
    ap.add_argument("--camera", required=True, help="file with --eye= --look= --up= --fov= (speed_accuracy --export-obj)")
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--height", type=int, default=512)
    ap.add_argument("--spp", default="1,2,4,8,16,32,64", help="comma-separated sample counts")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--threads", type=int, default=0, help="Cycles threads, 0 = all cores")
    ap.add_argument("--max-bounces", type=int, default=1024)
    ap.add_argument("--emitter-subdiv", type=int, default=16, help="as in cycles_reference.py")
    ap.add_argument("--adaptive", action="store_true",
                    help="Cycles' adaptive sampling (default threshold); --spp values are maximum sample counts")
    ap.add_argument("--outdir", required=True)
    a = ap.parse_args(argv)
    if bool(a.obj) == bool(a.gltf):
        ap.error("give exactly one of --obj and --gltf")
    with open(a.camera, "r", encoding="utf-8") as f:
        cam = argparse.ArgumentParser()
        cam.add_argument("--eye", type=cr.parse_vec3, required=True)
        cam.add_argument("--look", type=cr.parse_vec3, required=True)
        cam.add_argument("--up", type=cr.parse_vec3, required=True)
        cam.add_argument("--fov", type=float, required=True)
        c = cam.parse_args(shlex.split(f.read()))
    a.eye, a.look, a.up, a.fov = c.eye, c.look, c.up, c.fov
    a.spp_list = [int(s) for s in a.spp.split(",") if s.strip()]
    if not a.spp_list or min(a.spp_list) <= 0:
        ap.error("--spp needs positive sample counts")
    a.spp = a.spp_list[0]
    a.out = os.path.join(a.outdir, "spp_%d.exr" % a.spp)
    return a


def main():
    a = parse_args()
    os.makedirs(a.outdir, exist_ok=True)
    for stale in ("done", "times.csv"):
        if os.path.exists(os.path.join(a.outdir, stale)):
            os.remove(os.path.join(a.outdir, stale))
    cr.clear_scene()
    scene = bpy.context.scene
    if a.gltf:
        triangles = cr.import_gltf(scene, a)
    else:
        verts, tris, tri_mat, materials = cr.parse_obj(a.obj)
        if not tris:
            raise SystemExit("%s: no faces" % a.obj)
        verts, tris, tri_mat = cr.subdivide_emitters(verts, tris, tri_mat, materials, a.emitter_subdiv)
        cr.build_mesh(scene, verts, tris, tri_mat, materials)
        triangles = len(tris)
    cr.build_camera(scene, a)
    cr.configure_render(scene, a)
    if a.adaptive:
        scene.cycles.use_adaptive_sampling = True
    scene.cycles.samples = 1
    scene.render.filepath = os.path.abspath(os.path.join(a.outdir, "warmup.exr"))
    bpy.ops.render.render(write_still=True)
    os.remove(scene.render.filepath)
    print("cycles_sweep: %s: %d triangles; %dx%d, spp %s, threads %s, adaptive sampling %s"
          % (a.obj or a.gltf, triangles, a.width, a.height, a.spp_list, a.threads or "auto",
             "on (threshold %g, min samples %d = auto)" % (scene.cycles.adaptive_threshold,
                                                          scene.cycles.adaptive_min_samples)
             if a.adaptive else "off"), flush=True)
    rows = []
    for spp in a.spp_list:
        scene.cycles.samples = spp
        name = "spp_%d.exr" % spp
        scene.render.filepath = os.path.abspath(os.path.join(a.outdir, name))
        c0 = cpu_seconds()
        t0 = time.perf_counter()
        bpy.ops.render.render(write_still=True)
        t1 = time.perf_counter()
        cpu = cpu_seconds() - c0
        if not os.path.isfile(scene.render.filepath):
            raise SystemExit("render did not write %s" % scene.render.filepath)
        rows.append((spp, t1 - t0, cpu, name))
        print("cycles_sweep: spp %d: %.2f s wall, %.2f CPU-s" % (spp, t1 - t0, cpu), flush=True)
        with open(os.path.join(a.outdir, "times.csv"), "w", encoding="utf-8") as f:
            f.write("spp,wall_s,cpu_s,file\n")
            for r in rows:
                f.write("%d,%.4f,%.4f,%s\n" % r)
    open(os.path.join(a.outdir, "done"), "w").close()


if __name__ == "__main__":
    cr.run_as_script(main, "cycles_sweep")
