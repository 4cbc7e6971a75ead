# SPDX-License-Identifier: MIT
# trace_mesh.py — the README's Python example: load a mesh, build once, trace five rays, print the hits.
import sys

import numpy as np

import mbvh

scene = mbvh.load(sys.argv[1] if len(sys.argv) > 1 else "gen:sphere:64")  # or mbvh.Scene(vertices, triangles)
accel = mbvh.build(scene)                                                 # the BVH, built once
lo, hi = np.array(scene.bounds)
origins = np.tile((lo + hi) / 2 + [0, 0, hi[2] - lo[2]], (5, 1))          # above the middle, looking down
directions = np.array([[x, 0, -1] for x in np.linspace(-0.2, 0.2, 5)])
hits = accel.trace(origins, directions)                                   # t, u, v, prim: the .hits bytes
for i, h in enumerate(hits):
    print(f"ray {i}:", "miss" if h["prim"] == mbvh.MISS else f"triangle {h['prim']} at t = {h['t']:.4f}")
