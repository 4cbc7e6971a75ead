#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""python_bench.py — the measurements of bench/python.sh (issue 33): the Python module mbvh against
the program on the same rays, its per-call overhead, and the Python ray casters a mesh user would
otherwise reach for (Open3D, trimesh with embreex, embreex itself, NVIDIA Warp on its CPU device).
Three steps, each a subcommand:

    python_bench.py mbvh   --exe MBVH --scene S --rays R --hits H --occlusion O -o mbvh.json
        Debian's python3 with PYTHONPATH to the module; the standard library and numpy only.
        Rounds, one pass of each per round: `MBVH trace` (a process; its printed Mrays/s),
        accel.trace() timed around the call (wall clock), accel.bench() (the library's own timing,
        no Python in it); at THREADS and 1 thread, closest and any hit. The answers against the
        program's .hits / occlusion bytes; cpu against the reference traversal on every ray and the
        reference against the double-precision brute force on --brute rays (accel.check). Per-call
        overhead: the median time of a call in a loop of 1, 16 and 256 rays.
    python_bench.py peers  --scene S --rays R --hits H --occlusion O [--obj OBJ] -o peers.json
        The peers' python (a venv with them and numpy<2) with PYTHONPATH to the module too: each
        peer that imports, on the same rays and the triangles of mbvh.load (no loader of theirs in
        the timing): build, closest and any hit (median of --repeat after a warm-up, process CPU
        time beside the wall time: the threads it really used), a 1-ray call in a loop, and its
        answers against mbvh's ray by ray; the rays where they differ are classified in double
        precision (the peer's and mbvh's triangle tested in double; mbvh's answers on those rays
        against the double brute force, accel.check). --obj: the side-by-side task (load an .obj,
        trace, count hits) as each library's user writes it (the task_* functions below), run once.
    python_bench.py report --mbvh mbvh.json [--peers peers.json] --machine machine.txt -o python.json --md python.md
"""
import argparse
import inspect
import json
import os
import re
import statistics
import subprocess
import sys
import time

import numpy as np

REL_T = 1e-4  # answers at relative distance within this: the same surface (a tie, not an error)
EDGE = 1e-6   # |barycentric margin| within this: the ray grazes an edge (within float rounding of it)


# -- timing


def median(xs):
    return statistics.median(xs) if xs else 0.0


def timed(fn, repeat, warmup=1):
    """fn() after `warmup` calls, `repeat` times: (wall seconds, process CPU seconds) lists."""
    for _ in range(warmup):
        fn()
    wall, cpu = [], []
    for _ in range(repeat):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return wall, cpu


def speed(n, wall, cpu):
    m = median(wall)
    return {"rays": n, "seconds": wall, "cpu_seconds": cpu, "median_s": m, "mrays_per_s": n / m * 1e-6 if m else 0.0,
            "cpu_per_wall": median(cpu) / m if m else 0.0}


def per_call_us(fn, calls, reps):
    """Median over `reps` loops of `calls` calls of fn(): microseconds a call (the loop's own cost in)."""
    fn()
    per = []
    for _ in range(reps):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        per.append((time.perf_counter() - t0) / calls * 1e6)
    return {"median_us": median(per), "us": per, "calls": calls, "reps": reps}


# -- rays, answers


def load_rays(path):
    return np.fromfile(path, dtype=np.float32).reshape(-1, 8)


def lib_version(name):
    try:
        from importlib.metadata import version
        return version(name)
    except Exception:  # noqa: BLE001 (a missing or odd distribution: no version to name)
        return None


def machine():
    model, cores = "", os.cpu_count()
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=False).stdout
        model = re.search(r"^Model name:\s*(.+)$", out, re.M).group(1).strip()
    except Exception:  # noqa: BLE001
        pass
    return {"cpu": model, "cores": cores, "python": sys.version.split()[0], "executable": sys.executable,
            "numpy": np.__version__}


# -- step 1: mbvh against the program


CLI_LINE = re.compile(r"traced (\d+) rays \(([^)]*)\) in ([0-9.]+) ms: ([0-9.]+) Mrays/s; (\d+) (hits|occluded)")


def cli_trace(exe, scene, rays_path, query, threads):
    """One `mbvh trace` process on the ray file: its printed figures (the time around the backend's
    trace call alone: no load, no build, no writing; a cold call: first touch of the answers)."""
    out = subprocess.run([exe, "trace", scene, "--rays", rays_path, "--backend", "cpu", "--threads", str(threads),
                          "--query", query], capture_output=True, text=True, check=True).stdout
    m = CLI_LINE.search(out)
    if not m:
        raise SystemExit(f"python_bench: no 'traced ...' line in the output of mbvh trace:\n{out}")
    return {"rays": int(m.group(1)), "variant": m.group(2), "ms": float(m.group(3)), "mrays_per_s": float(m.group(4)),
            "hits": int(m.group(5))}


def step_mbvh(a):
    import mbvh
    res = {"machine": machine(), "mbvh": mbvh.__version__, "module": mbvh._mbvh.__file__, "scene": a.scene,
           "rays_file": a.rays, "threads": a.threads}
    t0 = time.perf_counter()
    scene = mbvh.load(a.scene)
    res["load_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    accel = mbvh.build(scene, threads=a.threads)
    res["build_s"] = time.perf_counter() - t0
    res["triangles"] = scene.triangle_count
    rays = load_rays(a.rays)
    n = len(rays)
    res["rays"] = n
    progress(f"mbvh: {scene.triangle_count} triangles, {n} rays")

    # -- the answers: the program's bytes, at THREADS and at 1 thread
    with open(a.hits, "rb") as f:
        want_hits = f.read()
    with open(a.occlusion, "rb") as f:
        want_occ = f.read()
    exact = {}
    for th in sorted({a.threads, 1}):
        h = accel.trace(rays, threads=th)
        o = accel.trace(rays, threads=th, query="any")
        exact[f"closest_threads{th}_equals_program"] = h.tobytes() == want_hits
        exact[f"any_threads{th}_equals_program"] = o.tobytes() == want_occ
        if th == a.threads:
            exact["hits"] = int((h["prim"] != mbvh.MISS).sum())
            exact["occluded"] = int(o.sum())
            exact["rays_differing_from_program"] = int(
                (h.view(np.uint8).reshape(n, 16) != np.frombuffer(want_hits, np.uint8).reshape(n, 16)).any(1).sum()) \
                if len(want_hits) == n * 16 else None
    if a.leak_scene:
        ls = mbvh.load(a.leak_scene)
        la = mbvh.build(ls, threads=a.threads)
        lr = load_rays(a.leak_rays)
        h, o = la.trace(lr, threads=a.threads), la.trace(lr, threads=a.threads, query="any")
        with open(a.leak_hits, "rb") as f, open(a.leak_occlusion, "rb") as g:
            exact["leaks"] = {"scene": a.leak_scene, "triangles": ls.triangle_count, "rays": len(lr),
                              "misses": int((h["prim"] == mbvh.MISS).sum()), "not_occluded": int((o == 0).sum()),
                              "equals_program": h.tobytes() == f.read() and o.tobytes() == g.read()}
    progress("mbvh: checking cpu against the reference and the double brute force")
    t0 = time.perf_counter()
    chk = accel.check(rays, backends=["cpu"], threads=a.threads, brute=min(a.brute, n))
    exact["check"] = chk
    exact["check_any"] = accel.check(rays, backends=["cpu"], threads=a.threads, query="any")
    exact["check_s"] = time.perf_counter() - t0
    res["exactness"] = exact

    # -- speed: rounds, one pass of each per round (a drift in the load slows all alike)
    configs = [("closest", a.threads), ("any", a.threads), ("closest", 1), ("any", 1)]
    runs = {f"{q}/{th}": {"cli": [], "py_wall": [], "py_cpu": [], "bench": []} for q, th in configs}
    for q, th in configs:  # warm: each backend made once, caches
        accel.trace(rays, threads=th, query=q)
        cli_trace(a.exe, a.scene, a.rays, q, th)
    for r in range(a.rounds):
        progress(f"mbvh: speed round {r + 1}/{a.rounds}")
        for q, th in configs:
            d = runs[f"{q}/{th}"]

            def py():
                c0, t0 = time.process_time(), time.perf_counter()
                accel.trace(rays, threads=th, query=q)
                d["py_wall"].append(time.perf_counter() - t0)
                d["py_cpu"].append(time.process_time() - c0)

            steps = [lambda: d["cli"].append(cli_trace(a.exe, a.scene, a.rays, q, th)["mrays_per_s"]), py,
                     lambda: d["bench"].append(accel.bench(rays, threads=th, query=q, repeat=1)["mrays_per_s"])]
            for k in range(3):  # the order rotates from round to round: none is always first after a process
                steps[(r + k) % 3]()
    sp = {}
    for key, d in runs.items():
        s = speed(n, d["py_wall"], d["py_cpu"])
        cli, bench = median(d["cli"]), median(d["bench"])
        sp[key] = {"query": key.split("/")[0], "threads": int(key.split("/")[1]), "python": s,
                   "cli_mrays_per_s": d["cli"], "cli_median": cli, "bench_mrays_per_s": d["bench"], "bench_median": bench,
                   "python_over_cli": s["mrays_per_s"] / cli if cli else 0.0,
                   "python_over_bench": s["mrays_per_s"] / bench if bench else 0.0}
    res["speed"] = sp
    b = accel.bench(rays, threads=a.threads, repeat=1)
    res["variant"] = {k: b[k] for k in ("runs_as", "describe", "layout", "traversal")}

    # -- per-call overhead: a call in a loop, 1, 16 and 256 rays; closest and any; 1 and THREADS threads
    oc = {}
    for th in sorted({1, a.threads}):
        for k in (1, 16, 256):
            batch = np.ascontiguousarray(rays[:k])
            calls = max(a.calls * 4 // (k + 3), 200)
            for q in ("closest", "any"):
                progress(f"mbvh: per-call overhead, {k} rays, {q}, {th} thread(s)")
                oc[f"{q}/{k}/{th}"] = dict(per_call_us(lambda b=batch, q=q, th=th: accel.trace(b, threads=th, query=q),
                                                       calls, a.call_reps), query=q, rays=k, threads=th)
    one = np.ascontiguousarray(rays[:1])
    o1, d1 = np.ascontiguousarray(rays[:1, 0:3]), np.ascontiguousarray(rays[:1, 4:7])
    th = a.threads
    forms = [  # (the call, a note)
        ("accel.trace(rays)", "rays (1, 8) float32", lambda: accel.trace(one, threads=th)),
        ("accel.trace(origins, directions)", "(1, 3) each: the (1, 8) records made first", lambda: accel.trace(o1, d1, threads=th)),
        ("accel._a.trace(rays, ...)", "the compiled call alone, no Python wrapper",
         lambda: accel._a.trace(one, "cpu", "closest", th)),
        ("accel.intersects_first(origins, directions)", "trimesh's call: -1 for a miss, int64",
         lambda: accel.intersects_first(o1, d1, threads=th)),
        ("accel.triangle_count", "a property: the floor of any pybind11 call", lambda: accel.triangle_count),
    ]
    res["overhead"] = oc
    res["overhead_forms"] = {call: dict(per_call_us(fn, a.calls, a.call_reps), threads=th, note=note)
                             for call, note, fn in forms}
    write_json(a.out, res)


# -- step 2: the peers


def hits_of(path, n):
    h = np.fromfile(path, dtype=[("t", "<f4"), ("u", "<f4"), ("v", "<f4"), ("prim", "<u4")])
    if len(h) != n:
        raise SystemExit(f"python_bench: {path} holds {len(h)} hits, the ray file {n} rays")
    prim = np.where(h["prim"] != 0xFFFFFFFF, h["prim"].astype(np.int64), -1)
    return prim, h["t"]


def double_test(rays, idx, prim, V, T):
    """The rays idx against triangles prim in double precision: (t along the ray, barycentric
    margin: the smallest of the three barycentric coordinates, >= 0 inside, < 0 outside by that
    fraction of the triangle). NaN where the ray is parallel to the plane."""
    r = rays[idx].astype(np.float64)
    o, d = r[:, 0:3], r[:, 4:7]
    tri = T[prim]
    v0, v1, v2 = V[tri[:, 0]], V[tri[:, 1]], V[tri[:, 2]]
    e1, e2 = v1 - v0, v2 - v0
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = o - v0
        u = np.einsum("ij,ij->i", s, p) * inv
        qv = np.cross(s, e1)
        v = np.einsum("ij,ij->i", d, qv) * inv
        t = np.einsum("ij,ij->i", e2, qv) * inv
    margin = np.minimum(np.minimum(u, v), 1 - u - v)
    return t, margin


def compare_closest(rays, mprim, peer_prim, V, T):
    """A peer's closest hits (triangle index, -1 a miss) against mbvh's, ray by ray: agreements,
    ties (different triangles at one distance), disagreements classified in double precision."""
    n = len(rays)
    diff = np.flatnonzero(mprim != peer_prim)
    out = {"rays": n, "peer_hits": int((peer_prim >= 0).sum()), "mbvh_hits": int((mprim >= 0).sum()),
           "same_triangle_or_both_miss": int(n - len(diff)), "differ": int(len(diff))}
    cls = {"tie: another triangle at the same distance": 0,
           "peer hit, mbvh miss: the ray misses the peer's triangle in double (peer false hit)": 0,
           "peer hit, mbvh miss: edge graze (within 1e-6 of the peer's triangle's edge)": 0,
           "peer hit, mbvh miss: a clear hit in double (mbvh missed it)": 0,
           "peer miss, mbvh hit: a clear hit in double (peer leak)": 0,
           "peer miss, mbvh hit: edge graze (within 1e-6 of mbvh's triangle's edge)": 0,
           "peer miss, mbvh hit: the ray misses mbvh's triangle in double (mbvh false hit)": 0,
           "peer farther: mbvh's nearer triangle a clear hit in double (peer leak)": 0,
           "peer farther: mbvh's nearer triangle an edge graze": 0,
           "peer farther: mbvh's nearer triangle missed in double (mbvh false hit)": 0,
           "peer nearer: its triangle a clear hit in double (mbvh missed it)": 0,
           "peer nearer: its triangle an edge graze": 0,
           "peer nearer: its triangle missed in double (peer false hit)": 0}
    if len(diff):
        mp, pp = mprim[diff], peer_prim[diff]
        Tm = np.where(mp >= 0, mp, 0)
        Tp = np.where(pp >= 0, pp, 0)
        tm, gm = double_test(rays, diff, Tm, V, T)
        tp, gp = double_test(rays, diff, Tp, V, T)
        for i in range(len(diff)):
            m_hit, p_hit = mp[i] >= 0, pp[i] >= 0
            def kind(g):
                return "clear" if g > EDGE else ("edge" if g >= -EDGE else "miss")
            if m_hit and p_hit and abs(tp[i] - tm[i]) <= REL_T * max(abs(tm[i]), 1e-30):
                cls["tie: another triangle at the same distance"] += 1
            elif p_hit and not m_hit:
                k = kind(gp[i])
                cls[{"miss": "peer hit, mbvh miss: the ray misses the peer's triangle in double (peer false hit)",
                     "edge": "peer hit, mbvh miss: edge graze (within 1e-6 of the peer's triangle's edge)",
                     "clear": "peer hit, mbvh miss: a clear hit in double (mbvh missed it)"}[k]] += 1
            elif m_hit and not p_hit:
                k = kind(gm[i])
                cls[{"clear": "peer miss, mbvh hit: a clear hit in double (peer leak)",
                     "edge": "peer miss, mbvh hit: edge graze (within 1e-6 of mbvh's triangle's edge)",
                     "miss": "peer miss, mbvh hit: the ray misses mbvh's triangle in double (mbvh false hit)"}[k]] += 1
            elif tp[i] > tm[i]:
                k = kind(gm[i])
                cls[{"clear": "peer farther: mbvh's nearer triangle a clear hit in double (peer leak)",
                     "edge": "peer farther: mbvh's nearer triangle an edge graze",
                     "miss": "peer farther: mbvh's nearer triangle missed in double (mbvh false hit)"}[k]] += 1
            else:
                k = kind(gp[i])
                cls[{"clear": "peer nearer: its triangle a clear hit in double (mbvh missed it)",
                     "edge": "peer nearer: its triangle an edge graze",
                     "miss": "peer nearer: its triangle missed in double (peer false hit)"}[k]] += 1
    out["classified"] = {k: v for k, v in cls.items() if v}
    ties = cls["tie: another triangle at the same distance"]
    edges = sum(v for k, v in cls.items() if "graze" in k)
    out["ties"] = ties
    out["edge_grazes"] = edges
    out["peer_errors"] = sum(v for k, v in cls.items() if "peer false hit" in k or "peer leak" in k)
    out["mbvh_errors"] = sum(v for k, v in cls.items() if "mbvh missed" in k or "mbvh false hit" in k)
    out["hit_miss_disagreements"] = int(((mprim >= 0) != (peer_prim >= 0)).sum())
    out["different_surface"] = int(len(diff) - ties - out["hit_miss_disagreements"])
    return out


def compare_any(rays, mocc, mprim, peer_occ, V, T, accel, cap):
    """A peer's occlusion (bool) against mbvh's: disagreements; where mbvh says occluded and the
    peer not, mbvh's closest triangle tested in double (a clear hit: the peer leaked)."""
    diff = np.flatnonzero(mocc != peer_occ)
    out = {"rays": len(rays), "peer_occluded": int(peer_occ.sum()), "mbvh_occluded": int(mocc.sum()),
           "differ": int(len(diff))}
    leak = np.flatnonzero(mocc & ~peer_occ)
    extra = np.flatnonzero(~mocc & peer_occ)
    out["mbvh_occluded_peer_not"] = int(len(leak))
    out["peer_occluded_mbvh_not"] = int(len(extra))
    if len(leak):
        _, g = double_test(rays, leak, mprim[leak], V, T)
        out["mbvh_occluded_peer_not_clear_in_double"] = int((g > EDGE).sum())
        out["mbvh_occluded_peer_not_edge_graze"] = int(((g >= -EDGE) & (g <= EDGE)).sum())
    if len(extra):  # mbvh's miss on those rays against the brute force: a confirmed miss makes it a false hit
        sub = extra[:cap]
        chk = accel.check(np.ascontiguousarray(rays[sub]), backends=["cpu"], brute=len(sub))
        out["mbvh_vs_brute_force_on_peer_occluded_rays"] = {k: chk[-1][k] for k in ("rays", "equal", "ties", "mismatches")}
    return out


class Peer:
    """One library: name, version, threads note; build(V, T) then closest(rays) -> (prim int64
    with -1 for a miss), any(rays) -> bool, one(ray) for the per-call loop."""
    name = ""
    module = ""
    note = ""


def peer_open3d(threads):
    import open3d as o3d

    class P(Peer):
        name = "Open3D RaycastingScene"
        dist = "open3d-cpu" if lib_version("open3d-cpu") else "open3d"
        note = f"cast_rays / test_occlusions(nthreads={threads}); Embree inside, its own build"

        def build(self, V, T):
            self.s = o3d.t.geometry.RaycastingScene(nthreads=threads)
            self.s.add_triangles(o3d.core.Tensor.from_numpy(V), o3d.core.Tensor.from_numpy(T))

        def prep(self, rays):
            return o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays[:, [0, 1, 2, 4, 5, 6]]))

        def closest(self, r6):
            a = self.s.cast_rays(r6, nthreads=threads)
            p = a["primitive_ids"].numpy()
            return np.where(p != o3d.t.geometry.RaycastingScene.INVALID_ID, p.astype(np.int64), -1)

        def any(self, r6):
            return self.s.test_occlusions(r6, nthreads=threads).numpy().astype(bool)

    return P()


def peer_trimesh():
    import trimesh
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    class P(Peer):
        name = "trimesh RayMeshIntersector (embreex)"
        dist = "trimesh"
        note = "intersects_first / intersects_any; embreex underneath, one ray at a time on the calling thread"

        def build(self, V, T):
            self.m = trimesh.Trimesh(V, T, process=False)
            self.r = RayMeshIntersector(self.m)

        def prep(self, rays):
            return np.ascontiguousarray(rays[:, 0:3]), np.ascontiguousarray(rays[:, 4:7])

        def closest(self, od):
            return self.r.intersects_first(*od).astype(np.int64)

        def any(self, od):
            return self.r.intersects_any(*od)

    return P()


def peer_embreex(robust):
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    class P(Peer):
        name = "embreex EmbreeScene" + (" (robust=True)" if robust else "")
        dist = "embreex"
        note = "scene.run(query='INTERSECT' / 'OCCLUDED'); one rtcIntersect1 a ray on the calling thread"

        def build(self, V, T):
            self.s = rtcore_scene.EmbreeScene(robust=robust)
            TriangleMesh(self.s, V, T.astype(np.int32))

        def prep(self, rays):
            return np.ascontiguousarray(rays[:, 0:3]), np.ascontiguousarray(rays[:, 4:7])

        def closest(self, od):
            return self.s.run(*od).astype(np.int64)

        def any(self, od):
            return self.s.run(*od, query="OCCLUDED") != -1

    return P()


_warp_kernels = None


def warp_kernels():
    """The Warp kernels, defined on first use (Warp compiles them from this file's source)."""
    global _warp_kernels
    if _warp_kernels is None:
        import warp as wp

        @wp.kernel
        def closest(mesh: wp.uint64, o: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3),
                    face: wp.array(dtype=wp.int32)):
            i = wp.tid()
            q = wp.mesh_query_ray(mesh, o[i], d[i], 1.0e30)
            face[i] = wp.where(q.result, q.face, -1)

        @wp.kernel
        def anyhit(mesh: wp.uint64, o: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3),
                   hit: wp.array(dtype=wp.int32)):
            i = wp.tid()
            hit[i] = wp.where(wp.mesh_query_ray_anyhit(mesh, o[i], d[i], 1.0e30), 1, 0)

        _warp_kernels = (closest, anyhit)
    return _warp_kernels


def peer_warp():
    import warp as wp
    wp.config.quiet = True
    wp.init()

    class P(Peer):
        name = "Warp wp.Mesh (device cpu)"
        dist = "warp-lang"
        note = "mesh_query_ray / mesh_query_ray_anyhit kernels launched on device \"cpu\" (a serial loop over the launch)"

        def build(self, V, T):
            self.k = warp_kernels()
            self.mesh = wp.Mesh(points=wp.array(V, dtype=wp.vec3, device="cpu"),
                                indices=wp.array(T.astype(np.int32).ravel(), dtype=wp.int32, device="cpu"))

        def prep(self, rays):
            n = len(rays)
            return (wp.array(np.ascontiguousarray(rays[:, 0:3]), dtype=wp.vec3, device="cpu"),
                    wp.array(np.ascontiguousarray(rays[:, 4:7]), dtype=wp.vec3, device="cpu"),
                    wp.empty(n, dtype=wp.int32, device="cpu"), n)

        def closest(self, x):
            o, d, out, n = x
            wp.launch(self.k[0], dim=n, inputs=[self.mesh.id, o, d, out], device="cpu")
            return out.numpy().astype(np.int64)

        def any(self, x):
            o, d, out, n = x
            wp.launch(self.k[1], dim=n, inputs=[self.mesh.id, o, d, out], device="cpu")
            return out.numpy() != 0

    return P()


# -- the side-by-side task: load an .obj, trace the rays (origins, directions: (N, 3) float32), count hits
# (the functions' bodies are what docs/python.md shows; `report` counts their lines)


def task_mbvh(path, origins, directions):
    import mbvh
    accel = mbvh.build(mbvh.load(path))
    hits = accel.trace(origins, directions, threads=2)
    return int((hits["prim"] != mbvh.MISS).sum())


def task_trimesh(path, origins, directions):
    import trimesh  # mesh.ray is embreex's RayMeshIntersector where embreex is installed
    mesh = trimesh.load(path, force="mesh", process=False)
    index_tri = mesh.ray.intersects_first(origins, directions)
    return int((index_tri != -1).sum())


def task_open3d(path, origins, directions):
    import open3d as o3d
    mesh = o3d.t.io.read_triangle_mesh(path)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh)
    ans = scene.cast_rays(o3d.core.Tensor(np.hstack([origins, directions])), nthreads=2)
    return int(np.isfinite(ans["t_hit"].numpy()).sum())


def task_embreex(path, origins, directions):
    import trimesh  # embreex has no mesh loader
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh
    mesh = trimesh.load(path, force="mesh", process=False)
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, mesh.vertices.astype(np.float32), mesh.faces.astype(np.int32))
    prim = scene.run(origins, directions)
    return int((prim != -1).sum())


def task_warp(path, origins, directions):
    import trimesh  # warp has no mesh loader
    import warp as wp
    closest = warp_kernels()[0]  # the @wp.kernel `closest` above: mesh_query_ray, face or -1 per ray
    mesh = trimesh.load(path, force="mesh", process=False)
    wmesh = wp.Mesh(points=wp.array(mesh.vertices, dtype=wp.vec3, device="cpu"),
                    indices=wp.array(mesh.faces.astype(np.int32).ravel(), dtype=wp.int32, device="cpu"))
    face = wp.empty(len(origins), dtype=wp.int32, device="cpu")
    wp.launch(closest, dim=len(origins), device="cpu", inputs=[
        wmesh.id, wp.array(origins, dtype=wp.vec3, device="cpu"), wp.array(directions, dtype=wp.vec3, device="cpu"), face])
    return int((face.numpy() != -1).sum())


TASKS = {"mbvh": task_mbvh, "trimesh + embreex": task_trimesh, "Open3D": task_open3d, "embreex": task_embreex,
         "Warp (cpu)": task_warp}


def task_source(fn):
    """The task's code as a user writes it (the body, without `def`, `return` becomes `count =`),
    and its count of lines (no blank line, no comment-only line; the Warp kernel's lines counted)."""
    src = inspect.getsource(fn).splitlines()[1:]
    body = [ln[4:] for ln in src]
    body = [("count = " + ln[len("return "):]) if ln.startswith("return ") else ln for ln in body]
    if fn is task_warp:
        ksrc = inspect.getsource(warp_kernels).splitlines()
        start = next(i for i, ln in enumerate(ksrc) if "@wp.kernel" in ln)
        end = next(i for i, ln in enumerate(ksrc) if "@wp.kernel" in ln and i > start)
        kernel = [ln[8:] for ln in ksrc[start:end] if ln.strip()]
        body = [body[0], body[1]] + kernel + [ln for ln in body[2:] if "warp_kernels()" not in ln]
    lines = sum(1 for ln in body if ln.strip() and not ln.strip().startswith("#"))
    return "\n".join(body), lines


def brute_double(rays, idx, V, T):
    """The exact closest hit of the rays idx in double precision, by brute force over every triangle
    (numpy; a triangle counts when the ray meets it inside or on an edge, t > tmin): (t*, prim*, the
    triangles within REL_T of t* as a list per ray). -1 and inf for a miss."""
    v0 = V[T[:, 0]]
    e1, e2 = V[T[:, 1]] - v0, V[T[:, 2]] - v0
    ts, prims, near = [], [], []
    for i in idx:
        r = rays[i].astype(np.float64)
        o, d = r[0:3], r[4:7]
        p = np.cross(d, e2)
        det = (e1 * p).sum(1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            sv = o - v0
            u = (sv * p).sum(1) * inv
            q = np.cross(sv, e1)
            v = (q @ d) * inv
            t = (q * e2).sum(1) * inv
            ok = (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= r[3]) & (t <= r[7]) & (t > 0) & np.isfinite(t)
        k = np.flatnonzero(ok)
        if not len(k):
            ts.append(np.inf), prims.append(-1), near.append([])
            continue
        j = k[np.argmin(t[k])]
        ts.append(t[j]), prims.append(int(j)), near.append([int(x) for x in k[t[k] <= t[j] * (1 + REL_T)]])
    return np.array(ts), np.array(prims, dtype=np.int64), near


def truth_check(rays, sample, truth, mprim, mt, answers):
    """On the sampled rays, whose answers are at the exact closest distance: mbvh's and each peer's
    triangle among those within REL_T of the brute force's t* (or both a miss)."""
    t_star, p_star, near = truth[:3]
    right = lambda prim, j: (prim == -1) if p_star[j] == -1 else (prim in near[j])  # noqa: E731
    out = {"rays": int(len(sample)), "mbvh_right": sum(right(int(mprim[i]), j) for j, i in enumerate(sample))}
    hit = p_star >= 0
    rel = np.abs(mt[sample][hit].astype(np.float64) - t_star[hit]) / t_star[hit]
    out["mbvh_t_rel_error_max"] = float(rel.max()) if len(rel) else 0.0
    out["mbvh_t_rel_error_median"] = float(np.median(rel)) if len(rel) else 0.0
    out["peers_right"] = {k: sum(right(int(pr[i]), j) for j, i in enumerate(sample)) for k, pr in answers.items()}
    V, T = truth[3], truth[4]
    wrong = {}
    for name, pr in [("mbvh", mprim)] + list(answers.items()):
        rows = []
        for j, i in enumerate(sample):
            if right(int(pr[i]), j) or len(rows) >= 8:
                continue
            row = {"ray": int(i), "answer": int(pr[i]), "exact_prim": int(p_star[j]), "exact_t": float(t_star[j])}
            if pr[i] >= 0:
                td, g = double_test(rays, np.array([i]), np.array([pr[i]]), V, T)
                row.update(answer_t_double=float(td[0]), answer_margin=float(g[0]))
            if p_star[j] >= 0:
                row["exact_margin"] = float(double_test(rays, np.array([i]), np.array([p_star[j]]), V, T)[1][0])
            if name == "mbvh":
                row["mbvh_t"] = float(mt[i])
            rows.append(row)
        if rows:
            wrong[name] = rows
    out["wrong"] = wrong
    return out


PEER_MAKERS = [("open3d", lambda a: peer_open3d(a.threads)), ("trimesh", lambda a: peer_trimesh()),
               ("embreex", lambda a: peer_embreex(False)), ("embreex-robust", lambda a: peer_embreex(True)),
               ("warp", lambda a: peer_warp())]


def step_peers(a):
    import mbvh
    scene = mbvh.load(a.scene)
    accel = mbvh.build(scene)
    V = np.ascontiguousarray(scene.vertices, dtype=np.float32)
    T = np.ascontiguousarray(scene.triangles, dtype=np.uint32)
    V64, T64 = V.astype(np.float64), T.astype(np.int64)
    rays = load_rays(a.rays)
    n = len(rays)
    mprim, mt = hits_of(a.hits, n)
    mocc = np.fromfile(a.occlusion, dtype=np.uint8).astype(bool)
    res = {"machine": machine(), "scene": a.scene, "rays": n, "threads": a.threads, "peers": {}, "missing": {}}
    peers, answers = {}, {}
    for key, make in PEER_MAKERS:
        try:
            p = make(a)
        except Exception as e:  # noqa: BLE001 (not installed, or does not start: said in the results)
            res["missing"][key] = f"{type(e).__name__}: {e}"
            progress(f"peers: {key} is missing here ({type(e).__name__}: {e})")
            continue
        peers[key] = p
        progress(f"peers: {p.name}")
        r = {"name": p.name, "distribution": p.dist, "version": lib_version(p.dist), "note": p.note}
        t0 = time.perf_counter()
        p.build(V, T)
        x = p.prep(rays)
        first = p.closest(x)  # the first query (a lazy build: Embree commits the scene here)
        r["build_and_first_trace_s"] = time.perf_counter() - t0
        wall, cpu = timed(lambda: p.closest(x), a.repeat, warmup=0)
        r["closest"] = speed(n, wall, cpu)
        wall, cpu = timed(lambda: p.any(x), a.repeat)
        r["any"] = speed(n, wall, cpu)
        progress(f"peers: {p.name}: {r['closest']['mrays_per_s']:.3f} Mrays/s closest, "
                 f"{r['any']['mrays_per_s']:.3f} any; exactness")
        prim = p.closest(x)
        answers[key] = prim
        r["deterministic"] = bool(np.array_equal(prim, first))
        r["exact_closest"] = compare_closest(rays, mprim, prim, V64, T64)
        r["exact_any"] = compare_any(rays, mocc, mprim, p.any(x), V64, T64, accel, a.classify_cap)
        x1 = p.prep(np.ascontiguousarray(rays[:1]))
        r["overhead_1ray_closest"] = per_call_us(lambda: p.closest(x1), a.calls, a.call_reps)
        r["overhead_1ray_any"] = per_call_us(lambda: p.any(x1), a.calls, a.call_reps)
        res["peers"][key] = r
        del x
    # -- who is right where they differ: a sample of the rays where any peer differs from mbvh, against
    # the exact closest hit (double-precision brute force)
    if answers:
        union = np.flatnonzero(np.any([pr != mprim for pr in answers.values()], axis=0))
        sample = np.sort(np.random.default_rng(1).choice(union, min(a.truth_cap, len(union)), replace=False)) \
            if len(union) else union
        progress(f"peers: {len(union)} rays differ somewhere; {len(sample)} of them against the double brute force")
        t0 = time.perf_counter()
        truth = brute_double(rays, sample, V64, T64) + (V64, T64)
        res["truth"] = dict(truth_check(rays, sample, truth, mprim, mt, answers), rays_differing_anywhere=int(len(union)),
                            seconds=time.perf_counter() - t0)
    # -- leaks: rays from inside a closed mesh, half aimed at its vertices and edges; every one must hit
    if a.leak_scene:
        ls = mbvh.load(a.leak_scene)
        LV = np.ascontiguousarray(ls.vertices, dtype=np.float32)
        LT = np.ascontiguousarray(ls.triangles, dtype=np.uint32)
        lr = load_rays(a.leak_rays)
        lprim, _ = hits_of(a.leak_hits, len(lr))
        locc = np.fromfile(a.leak_occlusion, dtype=np.uint8).astype(bool)
        res["leaks"] = {"scene": a.leak_scene, "triangles": len(LT), "rays": len(lr),
                        "mbvh_misses": int((lprim < 0).sum()), "mbvh_not_occluded": int((~locc).sum()), "peers": {}}
        for key, p in peers.items():
            progress(f"peers: {p.name}: leaks on {a.leak_scene}")
            p.build(LV, LT)
            x = p.prep(lr)
            prim, occ = p.closest(x), p.any(x)
            res["leaks"]["peers"][key] = {"misses": int((prim < 0).sum()), "not_occluded": int((~occ).sum()),
                                          "triangle_differs": int((prim != lprim).sum())}
    # -- the side-by-side task, once each, on the .obj
    if a.obj:
        o, d = np.ascontiguousarray(rays[:, 0:3]), np.ascontiguousarray(rays[:, 4:7])
        res["tasks"] = {}
        for label, fn in TASKS.items():
            code, lines = task_source(fn)
            t = {"code": code, "lines": lines}
            progress(f"task: {label}")
            try:
                t0 = time.perf_counter()
                t["count"] = fn(a.obj, o, d)
                t["seconds"] = time.perf_counter() - t0
            except ImportError as e:
                t["error"] = f"not installed ({e.name})"
            except Exception as e:  # noqa: BLE001 (a peer failing: said in the table)
                t["error"] = f"{type(e).__name__}: {e}"
            res["tasks"][label] = t
    write_json(a.out, res)


# -- step 3: the table


def fmt(x, digits=2):
    return "–" if x is None else f"{x:.{digits}f}"


def step_report(a):
    m = load_json(a.mbvh)
    p = load_json(a.peers) if a.peers and os.path.exists(a.peers) else None
    mach = open(a.machine).read() if a.machine else ""
    doc = {"machine_txt": mach, "mbvh": m, "peers": p}
    write_json(a.out, doc)
    th = m["threads"]
    L = []
    L.append(f"Scene `{os.path.basename(m['scene'])}` ({m['triangles']:,} triangles), {m['rays']:,} random rays "
             f"(`mbvh rays --kind random`), mbvh {m['mbvh']} ({m['variant']['runs_as']}, "
             f"{m['variant']['layout']}/{m['variant']['traversal']}); Python {m['machine']['python']}, numpy "
             f"{m['machine']['numpy']}; {m['machine']['cpu']}, {m['machine']['cores']} cores.")
    L.append("")
    L.append("### The binding against the program")
    L.append("")
    L.append("Mrays/s, medians of the rounds (one pass of each per round). `mbvh trace`: the figure the program "
             "prints (a process per pass; the time around the backend's trace call, a cold call); `accel.bench()`: "
             "the library's timing of the same call, warm, no Python; Python: the wall time around "
             "`accel.trace(rays, threads=..)` (checking the rays, the call, the answers handed to numpy).")
    L.append("")
    L.append("| query | threads | `mbvh trace` | `accel.bench()` | Python `accel.trace()` | Python / program | "
             "Python / bench | CPU s / wall s (Python) |")
    L.append("|---|---|---|---|---|---|---|---|")
    for key, s in m["speed"].items():
        L.append(f"| {s['query']} | {s['threads']} | {fmt(s['cli_median'], 3)} | {fmt(s['bench_median'], 3)} | "
                 f"{fmt(s['python']['mrays_per_s'], 3)} | {fmt(s['python_over_cli'], 3)}x | "
                 f"{fmt(s['python_over_bench'], 3)}x | {fmt(s['python']['cpu_per_wall'], 2)} |")
    e = m["exactness"]
    ok = all(v for k, v in e.items() if k.endswith("equals_program"))
    L.append("")
    chk = e["check"]
    brute = chk[-1] if len(chk) > 1 else None
    L.append(f"Answers: {'byte for byte the program' + chr(39) + 's' if ok else 'NOT the program' + chr(39) + 's'} "
             f".hits and occlusion files at {th} and 1 thread ({e['hits']:,} hits, {e['occluded']:,} occluded); "
             f"cpu against the reference traversal: {chk[0]['bit_identical']:,} of {chk[0]['rays']:,} rays bit "
             f"identical" + (f"; the reference against the double-precision brute force on {brute['rays']:,} rays: "
                             f"{brute['mismatches']} mismatches ({brute['ties']} ties)" if brute else "") + ".")
    if e.get("leaks"):
        lm = e["leaks"]
        L.append("")
        L.append(f"Leaks: {lm['rays']:,} rays from inside the closed `{lm['scene']}`, half aimed at its vertices and "
                 f"edges: {lm['misses']} misses, {lm['not_occluded']} not occluded; the program's answers "
                 f"{'byte for byte' if lm['equals_program'] else 'NOT equal'}.")
    L.append("")
    L.append("### Per-call overhead")
    L.append("")
    L.append("Median microseconds a call of `accel.trace()` in a loop (the loop's cost included), rays "
             "`(k, 8)` float32; 1 thread and the threads above.")
    L.append("")
    ths = sorted({v["threads"] for v in m["overhead"].values()})
    head = "| rays | " + " | ".join(f"closest, {t} thr. | any, {t} thr." for t in ths) + " |"
    L.append(head)
    L.append("|---" * (1 + 2 * len(ths)) + "|")
    for k in (1, 16, 256):
        cells = []
        for t in ths:
            for q in ("closest", "any"):
                cells.append(fmt(m["overhead"][f"{q}/{k}/{t}"]["median_us"], 2))
        L.append(f"| {k} | " + " | ".join(cells) + " |")
    L.append("")
    L.append(f"One ray, {th} threads, other forms of the call:")
    L.append("")
    L.append("| call | | µs |")
    L.append("|---|---|---|")
    for call, v in m["overhead_forms"].items():
        L.append(f"| `{call}` | {v['note']} | {fmt(v['median_us'], 2)} |")
    if p:
        L.append("")
        L.append("### The peers")
        L.append("")
        L.append("The same rays and triangles (those of `mbvh.load`), each library's own build; Mrays/s the median of "
                 "the timed calls after a warm-up; CPU/wall: the process CPU time over the wall time of a call (the "
                 "threads it kept busy; Embree's TBB workers spinning idle after a build count too); 1-ray µs: the median of a 1-ray call in a loop; answers against "
                 "mbvh's: rays whose hit/miss or triangle differs, ties (another triangle at the same distance, "
                 f"relative {REL_T:g}) and edge grazes (within {EDGE:g} of an edge in barycentric terms, either "
                 "answer defensible) apart, and the rest attributed by testing both triangles in double precision.")
        L.append("")
        tr, lk = p.get("truth"), p.get("leaks")
        lm = m["exactness"].get("leaks")
        if tr:
            L.append(f"Exactness where they differ: {tr['rays_differing_anywhere']:,} rays have a peer's triangle or "
                     f"hit/miss differ from mbvh's; {tr['rays']:,} of them, sampled, against the exact closest hit "
                     f"(a numpy double-precision brute force over every triangle): an answer is right when its "
                     f"triangle lies within relative {REL_T:g} of the exact distance t* (or both miss). mbvh's float t "
                     f"on those rays: relative error to t* at most {tr['mbvh_t_rel_error_max']:.1e} (median "
                     f"{tr['mbvh_t_rel_error_median']:.1e}).")
            L.append("")
        if lk:
            L.append(f"Leaks: {lk['rays']:,} rays from inside the closed `{lk['scene']}` ({lk['triangles']:,} "
                     f"triangles), half aimed exactly at its vertices and edge midpoints (`mbvh rays --kind inside`): "
                     f"every one must hit; a miss (closest) or a not-occluded (any) is a ray that slipped through.")
            L.append("")
        L.append("| library | version | threads asked | closest Mrays/s | CPU/wall | any Mrays/s | 1-ray µs closest | "
                 "1-ray µs any | rays differing from mbvh (closest) | of them ties | edge grazes | peer errors | "
                 "mbvh errors | any-hit differing | right on the brute-force sample | leaks: misses / not occluded |")
        L.append("|---" * 16 + "|")
        mb = m["speed"]
        for t in ths:
            c, an = mb[f"closest/{t}"], mb[f"any/{t}"]
            L.append(f"| mbvh `accel.trace` | {m['mbvh']} | {t} | {fmt(c['python']['mrays_per_s'], 3)} | "
                     f"{fmt(c['python']['cpu_per_wall'], 2)} | {fmt(an['python']['mrays_per_s'], 3)} | "
                     f"{fmt(m['overhead'][f'closest/1/{t}']['median_us'], 2)} | "
                     f"{fmt(m['overhead'][f'any/1/{t}']['median_us'], 2)} | (the answers compared) | | | | | | "
                     + (f"{tr['mbvh_right']:,} / {tr['rays']:,}" if tr else "–") + " | "
                     + (f"{lm['misses']:,} / {lm['not_occluded']:,}" if lm else "–") + " |")
        for key, r in p["peers"].items():
            ec, ea = r["exact_closest"], r["exact_any"]
            threads = str(p["threads"]) if key == "open3d" else "1 (no option)"
            lp = lk["peers"].get(key) if lk else None
            L.append(f"| {r['name']} | {r['version']} | {threads} | {fmt(r['closest']['mrays_per_s'], 3)} | "
                     f"{fmt(r['closest']['cpu_per_wall'], 2)} | {fmt(r['any']['mrays_per_s'], 3)} | "
                     f"{fmt(r['overhead_1ray_closest']['median_us'], 1)} | {fmt(r['overhead_1ray_any']['median_us'], 1)} | "
                     f"{ec['differ']:,} | {ec['ties']:,} | {ec['edge_grazes']:,} | {ec['peer_errors']:,} | "
                     f"{ec['mbvh_errors']:,} | {ea['differ']:,} | "
                     + (f"{tr['peers_right'][key]:,} / {tr['rays']:,}" if tr else "–") + " | "
                     + (f"{lp['misses']:,} / {lp['not_occluded']:,}" if lp else "–") + " |")
        for key, why in p.get("missing", {}).items():
            L.append(f"| {key} | missing here: {why.splitlines()[0][:80]} |" + " |" * 14)
        if tr and tr.get("wrong"):
            L.append("")
            L.append("Answers judged wrong on the brute-force sample (the answer's triangle in double: its t and "
                     "barycentric margin; the exact closest triangle's margin, near 0: at an edge):")
            L.append("")
            for name, rows in tr["wrong"].items():
                cells = []
                for w in rows:
                    ans = (f"triangle {w['answer']} at t {w.get('answer_t_double', 0):.9g} (margin "
                           f"{w.get('answer_margin', 0):.2g})" if w["answer"] >= 0 else "a miss")
                    ex = (f"triangle {w['exact_prim']} at t* {w['exact_t']:.9g} (margin {w.get('exact_margin', 0):.2g})"
                          if w["exact_prim"] >= 0 else "a miss")
                    cells.append(f"ray {w['ray']:,}: {ans}, exact {ex}")
                L.append(f"- {name}: " + "; ".join(cells) + ".")
        L.append("")
        L.append("What the differing rays are, per peer (closest hit):")
        L.append("")
        for key, r in p["peers"].items():
            ec, ea = r["exact_closest"], r["exact_any"]
            L.append(f"- **{r['name']}** ({r['note']}): {ec['peer_hits']:,} hits (mbvh {ec['mbvh_hits']:,}); "
                     + ("; ".join(f"{k}: {v:,}" for k, v in ec["classified"].items()) or "no difference")
                     + f". Any hit: {ea['mbvh_occluded_peer_not']:,} rays occluded for mbvh, not for the peer"
                     + (f" ({ea.get('mbvh_occluded_peer_not_clear_in_double', 0):,} a clear hit in double, "
                        f"{ea.get('mbvh_occluded_peer_not_edge_graze', 0):,} edge grazes)" if ea['mbvh_occluded_peer_not'] else "")
                     + f", {ea['peer_occluded_mbvh_not']:,} the other way"
                     + (f" (mbvh's miss there against the C++ double brute force: "
                        f"{ea['mbvh_vs_brute_force_on_peer_occluded_rays']['mismatches']} mismatches)"
                        if ea.get('mbvh_vs_brute_force_on_peer_occluded_rays') else "")
                     + ("" if r["deterministic"] else "; NOT deterministic between two calls") + ".")
        tasks = p.get("tasks")
        if tasks:
            L.append("")
            L.append("### The same task in each library")
            L.append("")
            L.append("Load the `.obj`, trace the rays (`origins`, `directions`: (N, 3) float32), count hits; "
                     "lines: without blank and comment lines; seconds: one run, loading and building included.")
            L.append("")
            want = m["exactness"]["hits"]
            L.append(f"| library | lines | hits counted (mbvh's answers: {want:,}) | seconds (load + build + trace) |")
            L.append("|---|---|---|---|")
            for label, t in tasks.items():
                c = t.get("count")
                cell = t.get("error", "–") if c is None else f"{c:,}" + ("" if c == want else f" ({c - want:+,})")
                L.append(f"| {label} | {t['lines']} | {cell} | {fmt(t.get('seconds'), 2)} |")
            for label, t in tasks.items():
                L.append("")
                L.append(f"{label}:")
                L.append("")
                L.append("```python")
                L.append(t["code"])
                L.append("```")
    with open(a.md, "w") as f:
        f.write("\n".join(L) + "\n")
    print("\n".join(L))


# -- plumbing


def progress(msg):
    print(f"-- {msg}", file=sys.stderr, flush=True)


def load_json(path):
    with open(path) as f:
        return json.load(f)


def write_json(path, doc):
    with open(path, "w") as f:
        json.dump(doc, f, indent=1, default=lambda o: o.item() if hasattr(o, "item") else str(o))
        f.write("\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="step", required=True)
    for name in ("mbvh", "peers"):
        s = sub.add_parser(name)
        s.add_argument("--scene", required=True)
        s.add_argument("--rays", required=True)
        s.add_argument("--hits", required=True, help="the program's .hits of the rays (closest, THREADS)")
        s.add_argument("--occlusion", required=True, help="the program's occlusion bytes of the rays (any)")
        s.add_argument("--threads", type=int, default=2)
        s.add_argument("--calls", type=int, default=20000, help="calls a loop (1 ray; fewer for more rays)")
        s.add_argument("--call-reps", type=int, default=5, help="loops (the median is kept)")
        s.add_argument("-o", "--out", required=True)
    sub.choices["mbvh"].add_argument("--exe", required=True, help="the mbvh program")
    sub.choices["mbvh"].add_argument("--rounds", type=int, default=7)
    sub.choices["mbvh"].add_argument("--brute", type=int, default=1000, help="rays against the double brute force")
    sub.choices["peers"].add_argument("--repeat", type=int, default=5)
    sub.choices["peers"].add_argument("--classify-cap", type=int, default=1000,
                                      help="at most this many differing rays checked against the brute force")
    sub.choices["peers"].add_argument("--obj", help="an .obj of the scene: run the side-by-side task on it")
    sub.choices["peers"].add_argument("--truth-cap", type=int, default=300,
                                      help="differing rays sampled for the double-precision brute force (numpy)")
    for name in ("mbvh", "peers"):
        for opt in ("--leak-scene", "--leak-rays", "--leak-hits", "--leak-occlusion"):
            sub.choices[name].add_argument(opt, help="the leak test: a closed mesh, rays from inside, the program's answers")
    r = sub.add_parser("report")
    r.add_argument("--mbvh", required=True)
    r.add_argument("--peers")
    r.add_argument("--machine")
    r.add_argument("-o", "--out", required=True)
    r.add_argument("--md", required=True)
    a = ap.parse_args()
    {"mbvh": step_mbvh, "peers": step_peers, "report": step_report}[a.step](a)


if __name__ == "__main__":
    main()
