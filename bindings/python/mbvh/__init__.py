# SPDX-License-Identifier: MIT
"""mbvh: exact BVH ray tracing on CPU SIMD, OpenCL and Vulkan, one build for every backend.

    import numpy as np, mbvh
    scene = mbvh.load("bunny.obj")                 # or mbvh.Scene(vertices, triangles): no copy
    accel = mbvh.build(scene)                      # the BVH, built once
    hits = accel.trace(origins, directions)        # structured array: t, u, v, prim
    hit = hits["prim"] != mbvh.MISS

Answers are watertight (Woop et al. 2013) and bit-identical across backends and thread counts;
``trace`` returns the bytes ``mbvh trace`` writes. Rays are one (N, 8) float32 array of the
project's ray records (origin, tmin, direction, tmax), read in place, or origins and directions.
Every library error is an ``mbvh.Error`` with the library's message; a bad array is a TypeError
or ValueError naming it. The GIL is released while building and tracing.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Optional, Sequence, Union

import numpy as np

from ._mbvh import HIT_DTYPE, MISS, STATS_DTYPE, Error, Scene, __version__, _build, backends, load, set_log

__all__ = ["Accel", "Error", "HIT_DTYPE", "Hits", "MISS", "STATS_DTYPE", "Scene", "__version__", "backends", "build",
           "load", "rays", "set_log"]


def rays(origins: Any, directions: Any, tmin: Any = 0.0, tmax: Any = math.inf) -> np.ndarray:
    """The (N, 8) float32 ray records of origins and directions ((N, 3) each, or one (3,) or
    (1, 3) for all), tmin and tmax (scalars or (N,)): origin, tmin, direction, tmax per row. A copy."""
    o = np.asarray(origins, dtype=np.float32)
    d = np.asarray(directions, dtype=np.float32)
    for name, a in (("origins", o), ("directions", d)):
        if a.ndim not in (1, 2) or a.shape[-1] != 3:
            raise ValueError(f"{name}: expected shape (N, 3) or (3,), got {a.shape}")
    n = max(o.shape[0] if o.ndim == 2 else 1, d.shape[0] if d.ndim == 2 else 1)
    for name, a in (("origins", o), ("directions", d)):
        if a.ndim == 2 and a.shape[0] not in (1, n):
            raise ValueError(f"{name}: {a.shape[0]} rows, the other array has {n}")
    r = np.empty((n, 8), dtype=np.float32)
    r[:, 0:3] = o
    r[:, 3] = tmin
    r[:, 4:7] = d
    r[:, 7] = tmax
    return r


@dataclass
class Hits:
    """Closest hits with what a mesh user asks next (Accel.closest_hit). Misses: hit False,
    t inf, prim -1, points and normals NaN."""
    hit: np.ndarray      # (N,) bool
    t: np.ndarray        # (N,) float32 distance along the ray, in units of the direction's length
    prim: np.ndarray     # (N,) int64 triangle index, -1 for a miss
    u: np.ndarray        # (N,) float32 barycentric weight of vertex 1
    v: np.ndarray        # (N,) float32 barycentric weight of vertex 2
    points: np.ndarray   # (N, 3) float64 hit point on the triangle, (1-u-v) v0 + u v1 + v v2
    normals: np.ndarray  # (N, 3) float64 unit geometric normal, (v1 - v0) x (v2 - v0): the winding's side


def _ray_array(rays_or_origins: Any, directions: Any, tmin: Any, tmax: Any) -> Any:
    return rays_or_origins if directions is None else rays(rays_or_origins, directions, tmin, tmax)


class Accel:
    """A build of a scene (mbvh.build): every backend and layout traces it. Backends are made on
    first use and kept with the build (a device's set-up and upload are paid once)."""

    __slots__ = ("_a",)

    def __init__(self, compiled: Any) -> None:
        self._a = compiled

    @property
    def scene(self) -> Scene:
        """The scene it was built from (kept alive with the build)."""
        return self._a.scene

    @property
    def triangle_count(self) -> int:
        return self._a.triangle_count

    @property
    def quality(self) -> str:
        return self._a.quality

    def hash(self) -> int:
        """64-bit hash of the build's bytes (equal across thread counts)."""
        return self._a.hash()

    def refit(self) -> None:
        """Refits the build to its scene's vertices after they were changed in place (the same
        triangles): boxes recomputed, topology kept. No trace may run meanwhile."""
        self._a.refit()

    def trace(self, rays_or_origins: Any, directions: Any = None, tmin: Any = 0.0, tmax: Any = math.inf, *,
              backend: str = "cpu", query: str = "closest", threads: int = 0, layout: Optional[str] = None,
              traversal: Optional[str] = None, precision: str = "robust",
              settings: Optional[Mapping[str, str]] = None, stats: bool = False) -> Any:
        """Traces rays: an (N, 8) float32 C-contiguous array of ray records (read in place, no copy),
        or origins and directions ((N, 3); tmin, tmax scalars or (N,)).

        query="closest": a structured array of dtype HIT_DTYPE (t, u, v, prim; a .hits file's
        bytes; a miss has prim == MISS and t == inf). query="any": uint8, 1 where occluded (an
        occlusion file's bytes). stats=True: a tuple (answers, STATS_DTYPE counters per ray).
        backend: a name of backends() ("cpu", "cpu-scalar", "opencl", "vulkan", "dacrt", ...);
        threads: CPU workers, 0 for every core; layout ("mbvh2", "mbvh4", "mbvh8"), traversal
        ("bitstack", "stack", "stack-ordered", "packet", ...) and precision ("robust", "exact",
        "fast") default as ``mbvh trace`` does; settings: backend settings ({"opencl.device": "cpu"}).
        """
        return self._a.trace(_ray_array(rays_or_origins, directions, tmin, tmax), backend, query, threads, layout,
                             traversal, precision, settings or {}, stats)

    def occluded(self, rays_or_origins: Any, directions: Any = None, tmin: Any = 0.0, tmax: Any = math.inf,
                 **options: Any) -> np.ndarray:
        """Any-hit queries (shadow rays): a bool array, True where something lies in [tmin, tmax]."""
        return self.trace(rays_or_origins, directions, tmin, tmax, query="any", **options).view(np.bool_)

    def closest_hit(self, rays_or_origins: Any, directions: Any = None, tmin: Any = 0.0, tmax: Any = math.inf,
                    **options: Any) -> Hits:
        """Closest hits with hit points and unit geometric normals (Hits)."""
        h = self.trace(rays_or_origins, directions, tmin, tmax, **options)
        hit = h["prim"] != MISS
        prim = np.where(hit, h["prim"].astype(np.int64), -1)
        points = np.full((len(h), 3), np.nan)
        normals = np.full((len(h), 3), np.nan)
        if hit.any():
            v0, v1, v2 = self._corners(prim[hit])
            u = h["u"][hit, None].astype(np.float64)
            v = h["v"][hit, None].astype(np.float64)
            points[hit] = (1 - u - v) * v0 + u * v1 + v * v2
            n = np.cross(v1 - v0, v2 - v0)
            normals[hit] = n / np.linalg.norm(n, axis=1, keepdims=True)
        return Hits(hit, h["t"], prim, h["u"], h["v"], points, normals)

    def intersects_first(self, ray_origins: Any, ray_directions: Any, **options: Any) -> np.ndarray:
        """The first triangle each ray hits, -1 for a miss (trimesh's ray.intersects_first)."""
        p = self.trace(ray_origins, ray_directions, **options)["prim"]
        return np.where(p != MISS, p.astype(np.int64), -1)

    def intersects_any(self, ray_origins: Any, ray_directions: Any, **options: Any) -> np.ndarray:
        """Whether each ray hits anything (trimesh's ray.intersects_any)."""
        return self.occluded(ray_origins, ray_directions, **options)

    def intersects_location(self, ray_origins: Any, ray_directions: Any, multiple_hits: bool = True,
                            max_hits: int = 1024, **options: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(locations (K, 3), index_ray (K,), index_tri (K,)) of the rays' hits, as trimesh's
        ray.intersects_location: every surface each ray crosses (multiple_hits, sorted by ray, then
        distance; at most max_hits a ray), or only the first. A surface met at one distance through
        a shared edge or vertex counts once."""
        if not multiple_hits:
            r, h = self._first_hits(ray_origins, ray_directions, options)
        else:
            r, h = self._all_hits(ray_origins, ray_directions, max_hits, options)
        prim = h["prim"].astype(np.int64)
        v0, v1, v2 = self._corners(prim)
        u = h["u"][:, None].astype(np.float64)
        v = h["v"][:, None].astype(np.float64)
        return (1 - u - v) * v0 + u * v1 + v * v2, r, prim

    def contains(self, points: Any, **options: Any) -> np.ndarray:
        """Whether each point lies inside the (closed) mesh, by the parity of the surfaces a ray
        from it crosses. The watertight test lets no ray slip through a shared edge; a ray that
        grazes an edge or vertex tangentially can still miscount, so three directions vote."""
        p = np.asarray(points, dtype=np.float32)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"points: expected shape (N, 3), got {p.shape}")
        votes = np.zeros(len(p), dtype=np.int64)
        for d in _CONTAINS_DIRECTIONS:
            r, _ = self._all_hits(p, d, 1 << 20, options)
            votes += np.bincount(r, minlength=len(p)) % 2
        return votes >= 2

    def check(self, rays: Any, backends: Optional[Sequence[str]] = None, query: str = "closest", threads: int = 0,
              brute: int = 0, **options: Any) -> list[dict]:
        """Each backend's answers (default: every backend that starts here) against the reference
        traversal (cpu-scalar) ray by ray, differences classified as ``mbvh check`` does (a tie: the
        same distance within 4 ulp or a hit on an edge); brute: that many rays of the reference also
        against the double-precision brute force. A list of dicts (rays, bit_identical, equal, ties,
        mismatches, first_mismatches, backend, runs_as, traversal, layout)."""
        return self._a.check(rays, list(backends) if backends is not None else None, query, threads,
                             options.get("layout"), options.get("traversal"), options.get("precision", "robust"),
                             options.get("settings") or {}, brute)

    def bench(self, rays: Any, backend: str = "cpu", query: str = "closest", threads: int = 0, repeat: int = 5,
              **options: Any) -> dict:
        """Times trace() in the library (one warm-up, then `repeat` runs): a dict with seconds,
        median_seconds, mrays_per_s, backend, runs_as, describe, layout, traversal, query, rays."""
        return self._a.bench(rays, backend, query, threads, options.get("layout"), options.get("traversal"),
                             options.get("precision", "robust"), options.get("settings") or {}, repeat)

    def _corners(self, prim: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        s = self._a.scene
        tri = np.asarray(s.triangles)[prim]
        vert = np.asarray(s.vertices, dtype=np.float64)
        return vert[tri[:, 0]], vert[tri[:, 1]], vert[tri[:, 2]]

    def _first_hits(self, origins: Any, directions: Any, options: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        h = self.trace(origins, directions, **options)
        idx = np.flatnonzero(h["prim"] != MISS)
        return idx, h[idx]

    def _all_hits(self, origins: Any, directions: Any, max_hits: int,
                  options: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        # every hit along each ray: trace, then again from just past the hit (tmin is inclusive, so
        # the next float after t skips the surface just found and its edge neighbours at that t)
        r = rays(origins, directions)
        active = np.arange(len(r))
        found_rays, found_hits = [], []
        for _ in range(max_hits):
            if active.size == 0:
                break
            h = self.trace(np.ascontiguousarray(r[active]), **options)
            hit = h["prim"] != MISS
            active, h = active[hit], h[hit]
            found_rays.append(active)
            found_hits.append(h)
            r[active, 3] = np.nextafter(h["t"], np.float32(np.inf))
        if not found_rays:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=HIT_DTYPE)
        index = np.concatenate(found_rays)
        hits = np.concatenate(found_hits)
        order = np.argsort(index, kind="stable")  # by ray, then distance (the order they were found)
        return index[order], hits[order]

    def __repr__(self) -> str:
        return f"<mbvh.Accel of {self.scene!r}: {self.quality} quality>"


# contains(): three directions with no simple ratio between their components, so an axis-aligned
# edge or face of a mesh is not grazed by all of them at once
_CONTAINS_DIRECTIONS = [np.array(d, dtype=np.float32) / np.linalg.norm(d) for d in
                        ((0.5773, 0.6133, 0.5393), (-0.7071, 0.1379, 0.6935), (0.2113, -0.8660, -0.4532))]


def build(scene: Union[Scene, str], quality: str = "medium", threads: int = 0, cache_dir: Optional[str] = None,
          max_leaf: int = 8, bins: int = 32) -> Accel:
    """Builds the BVH of a scene (or of a path or generator spec, loaded first). quality: "low"
    (LBVH), "medium" (binned SAH, the default), "high" (spatial splits) or "none" (the dacrt
    backends only); threads: 0 for every core (the result does not depend on it); cache_dir: read
    the build from this BVH cache when it holds it, else build and write it there."""
    if isinstance(scene, str):
        scene = load(scene)
    return Accel(_build(scene, quality, threads, cache_dir, max_leaf, bins))
