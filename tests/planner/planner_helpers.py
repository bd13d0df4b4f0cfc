"""Tiny synthetic piles, observations and data sets for planner tests (no physics)."""

from __future__ import annotations

import math

import numpy as np

from synth.data.shards import Manifest, Sample, ShardWriter, write_manifest
from synth.geometry.frames import OrthoGrid
from synth.geometry.grasp import Grasp
from synth.data.maps import encode_grasps
from synth.render.ortho import OrthoObservation


def bar_pile(n_logs: int, size: int = 32, extent: float = 5.0, seed: int = 0, spacing_px: int | None = None,
             n_obstacles: int = 0):
    """Logs as horizontal bars (along pile x), 0.16 m high, stacked in rows; returns
    (intensity, depth, instance, log row centres [px])."""
    rng = np.random.default_rng(seed)
    inst = np.zeros((size, size), np.int16)
    height = np.zeros((size, size), np.float32)
    thick = max(1, round(0.16 / (extent / size)))
    spacing = spacing_px or thick + 1
    top = size // 2 - (n_logs * spacing) // 2
    rows = []
    for i in range(n_logs):
        r = top + i * spacing
        c0 = int(rng.integers(size // 8, size // 4))
        inst[r : r + thick, c0 : c0 + size // 2] = i + 1
        height[r : r + thick, c0 : c0 + size // 2] = 0.16
        rows.append(r + (thick - 1) / 2)
    for j in range(n_obstacles):
        inst[1 + 2 * j : 3 + 2 * j, size - 3 : size - 1] = 1000 + j
    intensity = (0.3 + 0.5 * (inst > 0) + 0.05 * rng.random((size, size))).astype(np.float32)
    depth = (5.0 - height).astype(np.float32)
    return intensity, depth, inst, rows


def observation(n_logs: int, size: int = 32, seed: int = 0, extent: float = 5.0, **kw) -> OrthoObservation:
    inten, depth, inst, _ = bar_pile(n_logs, size, extent=extent, seed=seed, **kw)
    return OrthoObservation(intensity=inten[None], depth=depth, instance=inst, extent_m=extent, camera_height_m=5.0,
                            n_logs=n_logs, n_obstacles=int((inst >= 1000).any()))


def subset_grasp(inst: np.ndarray, subset, grid: OrthoGrid) -> Grasp:
    """A plausible grasp across the subset's bars: centre between them, closing axis along y."""
    m = np.isin(inst, [i + 1 for i in subset])
    rows, cols = np.nonzero(m)
    x, y = grid.pixel_to_pile(rows.mean(), cols.mean())
    ys = grid.pixel_to_pile(rows, cols)[1]
    width = float(np.clip(ys.max() - ys.min() + 0.4, 0.30, 1.55))
    return Grasp(float(x), float(y), math.pi / 2, width)


def make_dataset(out_dir, n_piles: int = 6, n_logs: int = 3, size: int = 32, shards: int = 2) -> Manifest:
    grid = OrthoGrid(size, 5.0)
    infos = []
    per = math.ceil(n_piles / shards)
    for s in range(shards):
        w = ShardWriter(out_dir, "t", s)
        for p in range(s * per, min(n_piles, (s + 1) * per)):
            inten, depth, inst, _ = bar_pile(n_logs, size, seed=p)
            for subset in [(i,) for i in range(n_logs)] + [tuple(range(n_logs))]:
                g = subset_grasp(inst, subset, grid)
                maps = encode_grasps(grid, [g], [0.95])
                w.add(Sample(pile_id=f"pile_{p:03d}", render=0, subset=subset, intensity=inten, depth=depth,
                             target_mask=np.isin(inst, [i + 1 for i in subset]), maps=maps,
                             grasps=np.array([[g.x_m, g.y_m, g.phi_rad, g.width_m, 0.95]]), negative=False,
                             n_logs=n_logs))
        infos.append(w.close())
    man = Manifest(params={"test": True}, grid={"size_px": size, "extent_m": 5.0, "camera_height_m": 5.0},
                   shards=infos, summary={})
    write_manifest(out_dir, man)
    return man
