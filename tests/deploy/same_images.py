#!/usr/bin/python3
"""same_images.py A1 B1 [A2 B2 ...]: exit 0 when each image Ai holds the same bytes as Bi or, failing
that (other metadata), exactly the same pixels (OpenImageIO, every channel as float); else exit 1
naming the first pair that differs and how."""
import filecmp
import os
import sys

import OpenImageIO as oiio

paths = sys.argv[1:]
if not paths or len(paths) % 2:
    sys.exit("usage: same_images.py A1 B1 [A2 B2 ...]")
for a, b in zip(paths[0::2], paths[1::2]):
    for p in (a, b):
        if not os.path.isfile(p) or os.path.getsize(p) == 0:
            sys.exit(f"missing or empty: {p}")
    if filecmp.cmp(a, b, shallow=False):
        continue
    pa, pb = (oiio.ImageBuf(p).get_pixels(oiio.FLOAT) for p in (a, b))
    if pa is None or pb is None or pa.shape != pb.shape:
        sys.exit(f"{a} vs {b}: cannot compare: shapes {getattr(pa, 'shape', None)} vs {getattr(pb, 'shape', None)}")
    diff = pa != pb
    if diff.any():
        sys.exit(f"{a} vs {b}: {int(diff.sum())} of {diff.size} values differ")
    print(f"{a}: same {pa.shape} pixels as {os.path.basename(b)} (bytes differ)", file=sys.stderr)
