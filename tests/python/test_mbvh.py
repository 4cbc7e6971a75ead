# SPDX-License-Identifier: MIT
# The Python module against the program: every backend's answers byte for byte equal to
# `mbvh trace` on the same rays, no copy of arrays already in the right form, clear exceptions
# for bad arrays and bad input, the mesh helpers against a numpy brute force, threads, refit, cache.
# Run by ctest ("python: pytest tests/python") with PYTHONPATH at the build's python/ folder, MBVH
# the program and MBVH_SCENES_DIR the shared scenes.
import os
import subprocess
import threading

import numpy as np
import pytest

import mbvh

SCENES = os.environ.get("MBVH_SCENES_DIR", os.path.join(os.path.dirname(__file__), "../../../shared/scenes"))
CLI = os.environ.get("MBVH", "mbvh")
CORNELL = os.path.join(SCENES, "cornell_box.obj.zst")
BUNNY = os.path.join(SCENES, "bun_zipper.ply.zst")


def random_rays(scene, n, seed):
    """Origins in the scene's box widened by half, directions uniform on the sphere."""
    rng = np.random.default_rng(seed)
    lo, hi = (np.array(b, dtype=np.float64) for b in scene.bounds)
    c, e = (lo + hi) / 2, (hi - lo) * 0.75
    o = c + rng.uniform(-1, 1, (n, 3)) * e
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return mbvh.rays(o, d)


def unit_cube():
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    t = np.array([tri for a, b, c, d in quads for tri in ((a, b, c), (a, c, d))], dtype=np.uint32)
    return v, t


@pytest.fixture(scope="module")
def cornell():
    scene = mbvh.load(CORNELL)
    return scene, mbvh.build(scene)


def test_version_and_backends():
    assert mbvh.__version__.count(".") == 2
    built = mbvh.backends()
    assert {"cpu-scalar", "cpu", "dacrt", "dacrt-scalar"} <= set(built)
    runnable = mbvh.backends(runnable=True)
    assert "cpu-scalar" in runnable and set(runnable) <= set(built)


@pytest.mark.parametrize("query", ["closest", "any"])
def test_every_backend_equals_the_program_byte_for_byte(cornell, tmp_path, query):
    scene, accel = cornell
    rays = random_rays(scene, 4000, 1)
    ray_file = tmp_path / "rays.bin"
    ray_file.write_bytes(rays.tobytes())
    for backend in mbvh.backends(runnable=True):
        out = tmp_path / f"{backend}.{query}"
        precision = "robust"
        try:
            accel.trace(rays[:1], backend=backend, query=query)
        except mbvh.Error as e:  # a peer without robust precision (tinybvh: not watertight) says so
            assert "precision" in str(e), e
            precision = "fast"
        subprocess.run([CLI, "--quiet", "trace", CORNELL, "--backend", backend, "--query", query, "--precision",
                        precision, "--rays", str(ray_file), "-o", str(out)], check=True, capture_output=True)
        answers = accel.trace(rays, backend=backend, query=query, threads=2, precision=precision)
        assert answers.dtype == (mbvh.HIT_DTYPE if query == "closest" else np.uint8)
        assert answers.tobytes() == out.read_bytes(), f"{backend} {query}: the module and `mbvh trace` differ"


def test_closest_hits_against_the_brute_force(cornell):
    scene, accel = cornell
    rays = random_rays(scene, 3000, 2)
    report = accel.check(rays, backends=["cpu", "dacrt"], brute=500)
    assert [r["mismatches"] for r in report] == [0, 0, 0], report
    assert report[0]["rays"] == 3000 and report[-1]["rays"] == 500
    occl = accel.check(rays, backends=["cpu"], query="any")
    assert occl[0]["mismatches"] == 0


def test_no_copy_of_arrays_in_the_right_form():
    v, t = unit_cube()
    scene = mbvh.Scene(v, t)
    assert scene._mesh_addresses() == (v.ctypes.data, t.ctypes.data)
    assert scene.vertices is v and scene.triangles is t
    # positions inside interleaved vertex records: a view with a row stride of 24 bytes
    records = np.zeros((len(v), 6), dtype=np.float32)
    records[:, :3] = v
    inter = mbvh.Scene(records[:, :3], t)
    assert inter._mesh_addresses()[0] == records.ctypes.data
    accel = mbvh.build(inter)
    rays = mbvh.rays([[0.5, 0.5, 2.0]], [[0, 0, -1]])
    assert accel._a._ray_address(rays) == rays.ctypes.data
    hits = accel.trace(rays)
    assert hits["t"][0] == 1.0 and hits["prim"][0] != mbvh.MISS
    # the results are the library's own storage, handed to numpy: not a copy that numpy owns
    assert not hits.flags.owndata and hits.base is not None


def test_owned_scene_arrays_are_views_that_keep_the_scene_alive():
    scene = mbvh.load("gen:sphere:16")
    v, t = scene.vertices, scene.triangles
    assert v.dtype == np.float32 and v.shape[1] == 3 and t.dtype == np.uint32 and t.shape == (scene.triangle_count, 3)
    del scene
    assert np.isfinite(v).all() and int(t.max()) < len(v)


def test_bad_arrays_are_clear_exceptions(cornell):
    _, accel = cornell
    rays = mbvh.rays(np.zeros((8, 3)), [[1, 0, 0]])
    with pytest.raises(TypeError, match="rays: expected dtype float32, got float64"):
        accel.trace(rays.astype(np.float64))
    with pytest.raises(ValueError, match=r"rays: expected shape \(N, 8\), got \(8, 7\)"):
        accel.trace(np.ascontiguousarray(rays[:, :7]))
    with pytest.raises(ValueError, match="not C-contiguous .row stride 64 bytes"):
        accel.trace(np.zeros((8, 16), np.float32)[:, :8])
    with pytest.raises(ValueError, match="not contiguous"):
        accel.trace(np.zeros((8, 16), np.float32)[:, ::2])
    with pytest.raises(ValueError, match="contiguous"):
        accel.trace(np.asfortranarray(rays))
    bad = rays.copy()
    bad[3, 5] = np.nan
    with pytest.raises(ValueError, match="rays: ray 3 has direction y = nan"):
        accel.trace(bad)
    degenerate = mbvh.rays(np.zeros((3, 3)), [[0, 0, 0], [1, 0, 0], [1, 0, 0]], tmin=[0, 2, 0], tmax=[1, 1, 1])
    assert (accel.trace(degenerate)["prim"][:2] == mbvh.MISS).all()  # zero direction, tmin > tmax: defined misses
    big = mbvh.rays(np.zeros((200000, 3)), [[1, 0, 0]])  # checked in chunks on the call's threads
    big[150001, 3] = -np.inf
    with pytest.raises(ValueError, match="rays: ray 150001 has tmin = -inf"):
        accel.trace(big, threads=2)
    big[150001, 3] = 0
    big[199999, 7] = -np.inf
    with pytest.raises(ValueError, match="ray 199999 has tmax = -inf"):
        accel.trace(big, threads=2)
    bad = rays.copy()
    bad[2, 0] = np.inf
    with pytest.raises(ValueError, match="ray 2 has origin x = inf"):
        accel.trace(bad)
    with pytest.raises(TypeError, match="expected a numpy array, got <class 'list'>"):
        accel._a.trace([[0.0] * 8], "cpu", "closest", 0, None, None, "robust", {}, False)
    v, t = unit_cube()
    with pytest.raises(TypeError, match=r"vertices: expected dtype float32, got float64 .*copy=True"):
        mbvh.Scene(v.astype(np.float64), t)
    with pytest.raises(TypeError, match="triangles: expected dtype uint32"):
        mbvh.Scene(v, t.astype(np.int64))
    with pytest.raises(ValueError, match=r"vertices: expected shape \(N, 3\), got \(8, 2\)"):
        mbvh.Scene(np.ascontiguousarray(v[:, :2]), t)
    with pytest.raises(ValueError, match="vertices: the array is not contiguous"):
        mbvh.Scene(np.asfortranarray(v), t)
    # copy=True converts what numpy can: float64 vertices, int64 indices
    s = mbvh.Scene(v.astype(np.float64), t.astype(np.int64), copy=True)
    assert s.triangle_count == 12 and s._mesh_addresses()[0] != v.ctypes.data
    with pytest.raises(ValueError, match="negative"):
        mbvh.Scene(v, -t.astype(np.int64), copy=True)
    with pytest.raises(mbvh.Error, match="vertex"):
        mbvh.Scene(v, t + 100)
    nan_v = v.copy()
    nan_v[0, 0] = np.nan
    with pytest.raises(mbvh.Error, match="NaN|nan"):
        mbvh.Scene(nan_v, t)


def test_library_errors_keep_their_message(tmp_path, cornell):
    _, accel = cornell
    missing = str(tmp_path / "missing.obj")
    with pytest.raises(mbvh.Error, match="missing.obj"):
        mbvh.load(missing)
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\n")
    with pytest.raises(mbvh.Error, match=r"bad.obj"):
        mbvh.build(mbvh.load(str(bad)))
    rays = mbvh.rays([[0, 0, 0]], [[1, 0, 0]])
    with pytest.raises(mbvh.Error, match="cpu-scalar"):  # the message lists the known backends
        accel.trace(rays, backend="no-such-backend")
    with pytest.raises(mbvh.Error, match="sideways"):
        accel.trace(rays, query="sideways")
    with pytest.raises(mbvh.Error, match="dacrt.nonsense"):
        accel.trace(rays, backend="dacrt", settings={"dacrt.nonsense": "1"})
    with pytest.raises(mbvh.Error, match="quality"):
        mbvh.build("gen:sphere:8", quality="superb")
    assert issubclass(mbvh.Error, RuntimeError)


def test_mesh_helpers_on_a_closed_cube():
    v, t = unit_cube()
    accel = mbvh.build(mbvh.Scene(v, t))
    rng = np.random.default_rng(3)
    pts = rng.uniform(-0.5, 1.5, (2000, 3)).astype(np.float32)
    inside = ((pts > 0) & (pts < 1)).all(axis=1)
    keep = (np.abs(pts - 0) > 1e-3).all(axis=1) & (np.abs(pts - 1) > 1e-3).all(axis=1)  # off the surface
    assert (accel.contains(pts[keep]) == inside[keep]).all()
    # along +x through the cube's middle: two surfaces, in order, on the faces x = 0 and x = 1
    o = np.array([[-1, 0.3, 0.6], [-1, 2, 2], [-1, 0.5, 0.5]], dtype=np.float32)  # the last: through an edge
    d = np.array([[1, 0, 0]] * 3, dtype=np.float32)
    loc, index_ray, index_tri = accel.intersects_location(o, d)
    assert index_ray.tolist() == [0, 0, 2, 2]
    assert np.allclose(loc[:, 0], [0, 1, 0, 1]) and np.allclose(loc[:2, 1:], [[0.3, 0.6]] * 2)
    first = accel.intersects_first(o, d)
    assert first[1] == -1 and first[0] == index_tri[0]
    assert accel.intersects_any(o, d).tolist() == [True, False, True]
    h = accel.closest_hit(o, d)
    assert h.hit.tolist() == [True, False, True] and h.prim[1] == -1 and np.isnan(h.points[1]).all()
    assert np.allclose(np.abs(h.normals[0]), [1, 0, 0]) and np.allclose(h.points[0], [0, 0.3, 0.6])
    loc1, r1, _ = accel.intersects_location(o, d, multiple_hits=False)
    assert r1.tolist() == [0, 2] and np.allclose(loc1[:, 0], 0)


def test_closest_hits_against_a_numpy_brute_force():
    scene = mbvh.load("gen:sphere:24")
    accel = mbvh.build(scene)
    rays = random_rays(scene, 300, 4)
    h = accel.closest_hit(rays)
    v = scene.vertices.astype(np.float64)
    tri = scene.triangles
    a, b, c = v[tri[:, 0]], v[tri[:, 1]], v[tri[:, 2]]
    for i in range(len(rays)):  # Moller-Trumbore in double over every triangle
        o, d = rays[i, 0:3].astype(np.float64), rays[i, 4:7].astype(np.float64)
        e1, e2 = b - a, c - a
        p = np.cross(d, e2)
        det = (e1 * p).sum(1)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = o - a
            u = (s * p).sum(1) / det
            q = np.cross(s, e1)
            w = (q * d).sum(1) / det
            tt = (q * e2).sum(1) / det
        ok = (u >= 0) & (w >= 0) & (u + w <= 1) & (tt > 0)
        best = np.min(tt[ok]) if ok.any() else np.inf
        if np.isinf(best):
            assert not h.hit[i]
        else:
            assert h.hit[i] and abs(h.t[i] - best) <= 1e-5 * max(1, best)


def test_threads_trace_at_once_and_agree(cornell):
    scene, accel = cornell
    rays = random_rays(scene, 20000, 5)
    expect = accel.trace(rays, threads=1)
    got = [None] * 4

    def run(k):
        got[k] = accel.trace(rays, backend="cpu" if k % 2 else "cpu-scalar", threads=1)

    workers = [threading.Thread(target=run, args=(k,)) for k in range(4)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    assert all(g.tobytes() == expect.tobytes() for g in got)


def test_refit_sees_vertices_moved_in_place():
    v, t = unit_cube()
    scene = mbvh.Scene(v, t)
    accel = mbvh.build(scene)
    ray = mbvh.rays([[0.5, 0.5, 5]], [[0, 0, -1]])
    assert accel.trace(ray)["t"][0] == 4.0
    v[:, 2] += 1  # the caller's array, which the scene views
    accel.refit()
    assert accel.trace(ray)["t"][0] == 3.0


def test_cache_dir_stats_and_traversals(tmp_path):
    scene = mbvh.load(BUNNY)
    a1 = mbvh.build(scene, cache_dir=str(tmp_path))
    assert any(p.suffix == ".mbvh" for p in tmp_path.iterdir())
    a2 = mbvh.build(scene, cache_dir=str(tmp_path))
    assert a1.hash() == a2.hash()
    rays = random_rays(scene, 2000, 6)
    base = a1.trace(rays)
    for layout, traversal in (("mbvh8", "stack"), ("mbvh4", "stack"), ("mbvh2", "bitstack")):
        assert a1.trace(rays, layout=layout, traversal=traversal).tobytes() == base.tobytes()
    hits, stats = a1.trace(rays, stats=True)
    assert stats.dtype == mbvh.STATS_DTYPE and len(stats) == len(rays) and stats["nodes"].sum() > 0
    none = mbvh.build(scene, quality="none")
    assert none.trace(rays, backend="dacrt").tobytes() == a1.trace(rays, backend="dacrt").tobytes()
    with pytest.raises(mbvh.Error, match="hierarchy"):
        none.trace(rays, backend="cpu")
    b = a1.bench(rays, repeat=2)
    assert b["rays"] == 2000 and len(b["seconds"]) == 2 and b["mrays_per_s"] > 0


def test_the_readme_example_runs():
    example = os.path.join(os.path.dirname(__file__), "../../examples/trace_mesh.py")
    out = subprocess.run([os.sys.executable, example, BUNNY], check=True, capture_output=True, text=True).stdout
    lines = out.splitlines()
    assert len(lines) == 5 and all(line.startswith(f"ray {i}: triangle ") for i, line in enumerate(lines)), out


def test_library_messages_go_to_the_log_callback_never_to_stderr():
    devices = [b for b in ("vulkan", "opencl-wide") if b in mbvh.backends(runnable=True)]
    if not devices:
        pytest.skip("no device backend starts here: nothing logs")
    code = ("import sys, mbvh\n"
            "lines = []\n"
            "if sys.argv[1] == 'log':\n"
            "    mbvh.set_log(lambda level, m: lines.append(level + ' ' + m))\n"
            "a = mbvh.build('gen:sphere:8')\n"
            f"for b in {devices!r}:\n"
            "    a.trace(mbvh.rays([[0, 0, 5]], [[0, 0, -1]]), backend=b)\n"
            "print('\\n'.join(lines))\n")
    quiet = subprocess.run([os.sys.executable, "-c", code, "none"], check=True, capture_output=True, text=True)
    assert quiet.stderr == "" and quiet.stdout.strip() == ""
    logged = subprocess.run([os.sys.executable, "-c", code, "log"], check=True, capture_output=True, text=True)
    assert logged.stderr == ""
    if "vulkan" in devices:
        assert "info vulkan: Vulkan device " in logged.stdout
    if "opencl-wide" in devices:
        assert "info opencl-wide: OpenCL device " in logged.stdout
    with pytest.raises(TypeError, match="callable"):
        mbvh.set_log(42)
