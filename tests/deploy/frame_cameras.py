#!/usr/bin/python3
"""frame_cameras.py SCENE.json FIRST LAST: one line per frame, "FRAME EYE LOOK UP FOV" (vectors as
x,y,z), the camera of the scene's camera animation at that frame as CameraAnimation::at computes it
(common/camera_animation.cpp: float keys, doubles in between, float results), for `epr render --eye
--look --up --fov` (9 significant digits give a float back exactly)."""
import json
import struct
import sys

f32 = lambda x: struct.unpack("f", struct.pack("f", x))[0]
keys = json.load(open(sys.argv[1]))["animation"]["camera"]
for frame in range(int(sys.argv[2]), int(sys.argv[3]) + 1):
    i = max(k for k in range(len(keys)) if keys[k]["frame"] <= frame)
    a = keys[i]
    b = keys[i + 1] if frame > a["frame"] and i + 1 < len(keys) else None
    t = (frame - a["frame"]) / (b["frame"] - a["frame"]) if b else 0.0
    lerp = lambda x, y: f32(f32(x) + (f32(y) - f32(x)) * t) if b else f32(x)
    vec = lambda n: ",".join("%.9g" % lerp(x, b[n][k] if b else x) for k, x in enumerate(a[n]))
    print(frame, vec("eye"), vec("look"), vec("up"), "%.9g" % lerp(a["fov"], b["fov"] if b else a["fov"]))
