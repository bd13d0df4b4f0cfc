"""Mesh files (OBJ) for pybullet: pentagonal prisms, frustums, convex rocks.

pybullet builds convex collision shapes and visual meshes from OBJ files; visual meshes given as
vertex arrays are dropped by the EGL renderer, so every mesh goes through a file. Files are named
by a hash of their content and cached in a per-user temporary folder, written atomically.
"""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
from pathlib import Path

import numpy as np

_CACHE = Path(tempfile.gettempdir()) / f"loggrasp-meshes-{os.getuid() if hasattr(os, 'getuid') else 0}"


def _write_cached(text: str, stem: str) -> str:
    digest = hashlib.sha1(text.encode()).hexdigest()[:16]
    path = _CACHE / f"{stem}-{digest}.obj"
    if not path.exists():
        _CACHE.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=_CACHE, suffix=".tmp")
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    return str(path)


def _obj(vertices: np.ndarray, faces: list[tuple[int, ...]], uvs: np.ndarray | None = None,
         normals: np.ndarray | None = None) -> str:
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    if uvs is not None:
        lines += [f"vt {u:.6f} {v:.6f}" for u, v in uvs]
    if normals is not None:
        lines += [f"vn {x:.6f} {y:.6f} {z:.6f}" for x, y, z in normals]
    for face in faces:
        if uvs is not None and normals is not None:
            lines.append("f " + " ".join(f"{i + 1}/{i + 1}/{i + 1}" for i in face))
        elif uvs is not None:
            lines.append("f " + " ".join(f"{i + 1}/{i + 1}" for i in face))
        else:
            lines.append("f " + " ".join(str(i + 1) for i in face))
    return "\n".join(lines) + "\n"


def unit_pentagonal_prism() -> str:
    """Prism along local x from -0.5 to 0.5, pentagon circumscribed by a circle of radius 0.5.

    Scale it by (length, diameter, diameter). Every vertex is referenced by a face (pybullet's
    hull comes out flat otherwise).
    """
    angles = [math.pi / 2 + 2 * math.pi * k / 5 for k in range(5)]
    ring = [(0.5 * math.cos(a), 0.5 * math.sin(a)) for a in angles]
    verts = [(-0.5, y, z) for y, z in ring] + [(0.5, y, z) for y, z in ring]
    faces: list[tuple[int, ...]] = [tuple(range(4, -1, -1)), tuple(range(5, 10))]
    for k in range(5):
        j = (k + 1) % 5
        faces.append((k, j, j + 5, k + 5))
    return _write_cached(_obj(np.array(verts), faces), "prism5")


def frustum(length_m: float, d0_m: float, d1_m: float, sides: int = 24, uv_m: float | None = None,
            axis: str = "x") -> str:
    """Closed truncated cone of true size: diameter ``d0_m`` at -length/2, ``d1_m`` at +length/2.

    ``axis`` is the local axis the cone runs along ("x" for logs, "z" for stumps). With ``uv_m``
    the texture coordinates are metric (one texture repeat per ``uv_m`` metres, unstretched);
    smooth normals are written for shading.
    """
    L = length_m
    a = np.linspace(0.0, 2 * np.pi, sides + 1)  # seam vertex duplicated for UVs
    verts, uvs, normals = [], [], []
    slope = (d0_m - d1_m) / 2 / L
    for end, d in ((-0.5, d0_m), (0.5, d1_m)):
        r = d / 2
        for ang in a:
            verts.append((end * L, r * math.cos(ang), r * math.sin(ang)))
            n = np.array([slope, math.cos(ang), math.sin(ang)])
            normals.append(tuple(n / np.linalg.norm(n)))
            circ = math.pi * (d0_m + d1_m) / 2
            uvs.append(((end + 0.5) * L, ang / (2 * math.pi) * circ))
    m = sides + 1
    faces: list[tuple[int, ...]] = []
    for k in range(sides):
        faces.append((k, m + k + 1, m + k))  # counter-clockwise seen from outside
        faces.append((k, k + 1, m + k + 1))
    # caps: centre vertices
    for end, d, base, flip in ((-0.5, d0_m, 0, True), (0.5, d1_m, m, False)):
        c = len(verts)
        verts.append((end * L, 0.0, 0.0))
        normals.append((-1.0 if flip else 1.0, 0.0, 0.0))
        uvs.append((0.0, 0.0))
        for k in range(sides):
            faces.append((c, base + k + 1, base + k) if flip else (c, base + k, base + k + 1))
        # end-cap rims share side vertices; normals are approximate (fine for rendering)
    v = np.array(verts)
    nrm = np.array(normals)
    if axis == "z":  # rotate x->z, y->y, z->-x
        v = np.stack([-v[:, 2], v[:, 1], v[:, 0]], axis=1)
        nrm = np.stack([-nrm[:, 2], nrm[:, 1], nrm[:, 0]], axis=1)
    uv = np.array(uvs) / (uv_m if uv_m else 1.0)
    return _write_cached(_obj(v, faces, uv, nrm), f"frustum{axis}")


def convex_hull_mesh(points_m: np.ndarray, uv_m: float | None = 0.5) -> str:
    """OBJ of the convex hull of ``points_m`` (local frame), with planar-projected UVs."""
    from scipy.spatial import ConvexHull

    pts = np.asarray(points_m, dtype=float)
    hull = ConvexHull(pts)
    used = np.unique(hull.simplices)
    remap = {int(old): new for new, old in enumerate(used)}
    verts = pts[used]
    centre = verts.mean(axis=0)
    faces = []
    for simplex, eq in zip(hull.simplices, hull.equations):
        tri = [remap[int(i)] for i in simplex]
        n = np.cross(verts[tri[1]] - verts[tri[0]], verts[tri[2]] - verts[tri[0]])
        if np.dot(n, eq[:3]) < 0:
            tri = tri[::-1]
        faces.append(tuple(tri))
    uvs = verts[:, :2] / (uv_m or 1.0)
    normals = verts - centre
    normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-12
    return _write_cached(_obj(verts, faces, uvs, normals), "hull")


def grid_mesh(heights_m: np.ndarray, extent_m: float, z_offset_m: float = 0.0, uv_m: float = 0.5) -> str:
    """OBJ of a square height grid (``[iy, ix]``, centred on the origin) with smooth normals and
    metric UVs (one texture repeat per ``uv_m``). Vertex z is ``height - z_offset_m``."""
    h = np.asarray(heights_m, dtype=float)
    n = h.shape[0]
    xs = np.linspace(-extent_m / 2, extent_m / 2, n)
    X, Y = np.meshgrid(xs, xs)
    verts = np.stack([X.ravel(), Y.ravel(), (h - z_offset_m).ravel()], axis=1)
    step = extent_m / (n - 1)
    gy, gx = np.gradient(h, step)
    normals = np.stack([-gx.ravel(), -gy.ravel(), np.ones(n * n)], axis=1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    uvs = verts[:, :2] / uv_m
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])  # counter-clockwise from above
    return _write_cached(_obj(verts, [tuple(f) for f in faces], uvs, normals), "grid")
